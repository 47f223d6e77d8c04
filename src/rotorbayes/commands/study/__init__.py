"""A whole study from an analysis file (:mod:`.analysis`: the stages run through the
commands, in order) and several at once (:mod:`.batch`)."""
