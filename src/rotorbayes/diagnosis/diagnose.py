"""The diagnosis of a fit: is the remaining error noise, and if not, what is missing?

:func:`diagnose` combines

1. the verdict: the residual RMS of every fitted channel against the noise floor (encoder
   quantisation, plus Gaussian noise if the user says the data have it);
2. the score tests of every catalogue effect that is off (:mod:`.score`), Holm-corrected;
3. the missing-torque map (:mod:`.torque`) for what the catalogue does not hold.

The verdict comes first and is a boolean, ``adequate``.  A catalogue effect is *claimed*
only if its test is significant after correction, it is not equivalent to the free
parameters, and the missing-torque map does not point at a variable the effect cannot
produce (an angle or a drift in time); otherwise the text names the strongest dependence
in words and points to writing a user effect (``docs/effects.md``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..inference.assess import AT_FLOOR
from ..inference.problem import Problem
from .score import EffectScore, score_tests
from .torque import TorqueMap, missing_torque

#: Significance level of the ranking (after Holm's correction).
LEVEL = 0.01
#: Missing-torque variables each catalogue effect can produce.
EXPLAINS = {
    "upper_asymmetric_coulomb": {"direction", "velocity"},
    "upper_asymmetric_viscous": {"direction", "velocity"},
    "lower_asymmetric_coulomb": {"direction", "velocity"},
    "lower_asymmetric_viscous": {"direction", "velocity"},
    "lower_stribeck": {"velocity", "direction"},
    "initial_torsion": {"torsion", "direction", "velocity"},
    "string_damping": {"torsion", "velocity"},
    "voltage_offset": {"input", "direction"},
    "input_delay": {"input_rate", "input"},
    "motor_deadzone": {"input", "velocity"},
}
#: Variables no catalogue effect produces: a strong dependence on them rules a claim out.
FOREIGN = {"angle_1", "angle_2", "time"}


@dataclass
class Diagnosis:
    """Verdict, ranking of catalogue effects and the missing-torque maps of one fit."""

    adequate: bool
    verdict: str
    rms_over_floor: dict[str, float]
    floor: dict[str, float]
    ranking: list[EffectScore]
    maps: list[TorqueMap]
    claimed: str | None
    advice: str
    ssr: float
    seconds: float
    noise_std: float = 0.0
    evidence: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "adequate": self.adequate,
            "verdict": self.verdict,
            "claimed_effect": self.claimed,
            "advice": self.advice,
            "evidence": self.evidence,
            "rms_over_floor": self.rms_over_floor,
            "floor_rad": self.floor,
            "noise_std_rad": self.noise_std,
            "ssr": self.ssr,
            "ranking": [s.as_dict() for s in self.ranking],
            "missing_torque": [m.as_dict() for m in self.maps],
            "level": LEVEL,
            "seconds": self.seconds,
        }

    def text(self) -> str:
        lines = [f"verdict: {'ADEQUATE' if self.adequate else 'INADEQUATE'} — {self.verdict}"]
        lines += [f"  {e}" for e in self.evidence]
        lines.append("")
        lines.append("catalogue effects that are off, best first by adjusted p (score tests "
                     f"at the fit; p adjusted by Holm over {len(self.ranking)} effects):")
        lines.append(f"  {'effect':<26} {'p':>9} {'p adj.':>9} {'pred. RMS/floor':>16}  "
                     "one-step estimate")
        for s in self.ranking:
            pred = ", ".join(f"{c} {v:.3g}" for c, v in s.predicted_rms_ratio.items())
            est = ", ".join(f"{n} = {v:.3g} {u}" if math.isfinite(v) else f"{n}: —"
                            for (n, v), u in zip(s.step.items(), s.units, strict=True))
            tag = ""
            if s.equivalent_to_free:
                tag = "  [equivalent to the free parameters: cannot be told apart]"
            elif s.alike:
                tag = f"  [indistinguishable here from {', '.join(s.alike)}]"
            lines.append(f"  {s.effect:<26} {s.p_value:9.2g} {s.p_adjusted:9.2g} "
                         f"{pred:>16}  {est}{tag}")
        lines.append("")
        lines.append("missing-torque map (measured angles, slip samples):")
        for m in self.maps:
            lines.append("  " + m.words())
        lines.append("")
        lines.append(self.advice)
        return "\n".join(lines)


def diagnose(
    problem: Problem,
    x: np.ndarray,
    *,
    noise_std: float = 0.0,
    n_blocks: int = 30,
    seed: int = 0,
) -> Diagnosis:
    """Diagnose the fit ``x`` of ``problem``.

    Parameters
    ----------
    noise_std : float
        Gaussian measurement noise [rad] the data carry besides encoder quantisation
        (0 for synthetic quantised data; the floor becomes ``sqrt(q²/12 + noise_std²)``).
    """
    t0 = time.perf_counter()
    floor, notes = problem.noise_floors(noise_std if noise_std else None)
    r = problem.residuals(x)
    if not np.all(np.isfinite(r)):
        raise ValueError("the model cannot be simulated at this fit; nothing to diagnose")
    ratios = problem.rms_over_floor(r, floor)
    worst = max(ratios.values())
    ranking = score_tests(problem, x, n_blocks=n_blocks, seed=seed, floor=floor)
    maps = missing_torque(problem, x)
    evidence = notes + [
        "residual RMS / noise floor: "
        + ", ".join(f"{c} {v:.2f} (floor {floor[c]:.2g} rad)" for c, v in ratios.items())
    ]
    significant = [s for s in ranking if s.p_adjusted < LEVEL and not s.equivalent_to_free]
    # A claim must also promise a fall of the error: an effect whose one-step prediction
    # does not lower the SSR (a non-smooth effect probed by a secant, far from the fit) is
    # significant but not the answer.
    promising = [s for s in significant if s.predicted_ssr < 0.99 * float(r @ r)]
    at_floor = worst <= AT_FLOOR
    adequate = at_floor and not significant
    strongest = max(
        (m for m in maps if m.strongest), key=lambda m: m.strongest[1], default=None
    )
    foreign = None
    if strongest is not None and strongest.strongest[0] in FOREIGN and \
            strongest.strongest[1] > 0.5 and strongest.rms > 2 * strongest.noise_rms:
        foreign = strongest
    claimed = None
    if adequate:
        verdict = (f"the remaining error is consistent with measurement noise (worst channel "
                   f"{worst:.2f}x the floor; no catalogue effect significant at "
                   f"{LEVEL:g} after correction)")
        advice = "Nothing to add: the model explains these data to the encoders' resolution."
    else:
        verdict = (f"the model does not explain the data: worst channel {worst:.3g}x the floor"
                   if not at_floor else
                   f"the error is at the floor ({worst:.2f}x) but "
                   f"{significant[0].effect} is significant")
        top = promising[0] if promising else (significant[0] if significant else None)
        if top is not None and top not in promising:
            top = None
        if top is not None and foreign is not None:
            # The foreign dependence vetoes the claim only if it clearly beats every
            # variable the top effect could produce, on the same disc's map.
            own = [r2 for var, r2 in foreign.ranking if var in EXPLAINS.get(top.effect, ())]
            if own and foreign.strongest[1] < max(own) + 0.2:
                foreign = None
        if top is not None and foreign is None:
            claimed = top.effect
            tie = [s.effect for s in significant[1:] if s.effect in top.alike]
            est = ", ".join(f"{n} ≈ {v:.3g} {u}" for (n, v), u in
                            zip(top.step.items(), top.units, strict=True))
            advice = (f"Most likely missing: {top.effect} — {top.physics} (p {top.p_adjusted:.2g}"
                      f" after correction; one-step estimate {est}).")
            if tie:
                advice += (f" These data cannot tell it from {', '.join(tie)} (their "
                           "corrections are nearly parallel); validation data or another "
                           "input can.")
            if top.equivalences:
                advice += " Registry: " + "; ".join(top.equivalences) + "."
            advice += (f"\nAdd it and refit: rotorbayes fit ... --p0 FIT/fit.json --add "
                       f"{top.effect}; then diagnose the new fit (one effect at a time).")
        else:
            where = foreign.words() if foreign else (
                strongest.words() if strongest else "no missing-torque map could be made")
            advice = ("No catalogue effect explains the residual"
                      + (f" (the best, {top.effect}, is significant but cannot produce the "
                         "dependence below)" if top is not None else "")
                      + f": {where}.\nWrite a user effect for it (docs/effects.md; "
                      "examples/angle_friction.py is a worked example) and add it with "
                      "--add FILE.py:NAME.")
    return Diagnosis(
        adequate=adequate,
        verdict=verdict,
        rms_over_floor=ratios,
        floor=floor,
        ranking=ranking,
        maps=maps,
        claimed=claimed,
        advice=advice,
        ssr=float(r @ r),
        seconds=time.perf_counter() - t0,
        noise_std=noise_std,
        evidence=evidence,
    )
