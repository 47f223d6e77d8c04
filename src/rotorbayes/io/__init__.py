"""Input and output: measurement files (:mod:`.measurements`), a rig's own files
(:mod:`.rigfiles`), encoder glitches found on loading (:mod:`.glitches`), TOML/JSON files
(:mod:`.tomlfile`), result folders written whole (:mod:`.outputs`; read back by
:mod:`rotorbayes.inference.results`), and the bundled examples (:mod:`.examples`)."""
