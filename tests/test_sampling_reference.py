"""The sampler's chains stay bit for bit what they were: the cases of
``tests/data/make_sampling_reference.py`` (serial and on threads, two ensembles, the fit
proposal re-centred, a run stopped on request and resumed, a short run continued on another
back-end, in-memory runs with other moves and starts) run again and compared, array by
array, with the chains that script wrote (``tests/data/sampling_reference.npz``).

The comparison with the file needs the libraries and the kind of processor that wrote it
(``tests/recorded.py``): under another numpy or scipy, or on a processor without AVX-512, the
fit proposal's eigendecomposition moves in its last bits, one acceptance differs and the
chains part. The cases' agreement among themselves is checked under any libraries."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
from recorded import recording_machine

DATA = Path(__file__).resolve().parent / "data"


def _script():
    spec = importlib.util.spec_from_file_location(
        "make_sampling_reference", DATA / "make_sampling_reference.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_chains_are_bit_for_bit_those_of_the_reference(tmp_path):
    script = _script()
    lp, x = script.problem()
    got = script.cases(lp, x, tmp_path)
    with np.load(DATA / "sampling_reference.npz") as ref:
        assert sorted(got) == sorted(ref.files)
        differ = [
            k
            for k in ref.files
            if not (got[k].dtype == ref[k].dtype and np.array_equal(got[k], ref[k]))
        ]
    if recording_machine():
        assert not differ, differ
    # The cases agree among themselves too: threads, stop and resume, and a continued short
    # run end with the serial run's chains.
    for tag in ("threads", "stopped", "short"):
        for e in ("ensemble0", "ensemble1"):
            assert np.array_equal(got[f"{tag}/{e}/chain"], got[f"serial/{e}/chain"])
    assert got["stopped_part/ensemble0/iteration"] == 40
