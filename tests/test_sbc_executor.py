"""SBC data sets run through the executor layer (issue 18 item 2): the same results serially
and on local threads, data set by data set (each has its own seed)."""

from __future__ import annotations

import importlib.util
from pathlib import Path


def _sbc():
    path = Path(__file__).resolve().parents[1] / "analyses" / "sbc.py"
    spec = importlib.util.spec_from_file_location("analyses_sbc", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_sbc_data_sets_serial_and_threads_agree():
    mod = _sbc()
    args = ["--case", "upper", "--datasets", "3", "--walkers", "8", "--steps", "30"]
    a = mod.main([*args, "--backend", "serial"])
    b = mod.main([*args, "--backend", "threads", "--workers", "2"])
    a.pop("seconds")
    b.pop("seconds")
    assert a == b
    assert len(a["k_m"]["ranks"]) == 3  # data set by data set, not only the coverage
