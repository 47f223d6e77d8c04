"""Figures: simulations, fits, friction curves, multistart spreads (:mod:`.plots`) and
posteriors (:mod:`.posterior`).  Diagnosis draws its own (:mod:`rotorbayes.diagnosis.figures`)."""
