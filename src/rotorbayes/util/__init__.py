"""Small utilities every layer may use: exit codes (:mod:`.exitcodes`), numbers printed
to their spread (:mod:`.numformat`), fit-quality metrics (:mod:`.metrics`) and the first
compile's message (:mod:`.coldstart`)."""

#: The package version (pyproject.toml says the same); here, in the bottom layer, so that
#: every layer can record it.
__version__ = "0.3.0"
