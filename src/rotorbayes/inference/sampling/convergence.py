"""Reading the ensembles' chains: burn-in and thinning from the integrated autocorrelation
time τ, and the warnings in words when the chains are too short (N > 50 τ per parameter),
or the acceptance is off for the moves used."""

from __future__ import annotations

import math

import numpy as np

from .moves import ACCEPTANCE
from .store import EnsembleRun


def burn_thin(runs: list[EnsembleRun]) -> tuple[int, int]:
    """Burn-in (2 max τ) and thinning (τ_min / 2), from all ensembles' τ."""
    taus = np.concatenate([r.tau for r in runs])
    taus = taus[np.isfinite(taus)]
    n = min(r.chain.shape[0] for r in runs)
    if taus.size == 0:
        return n // 2, 1
    burn = min(int(math.ceil(2 * taus.max())), n // 2)
    thin = max(1, int(taus.min() // 2))
    return burn, thin


def convergence(runs: list[EnsembleRun], names: list[str]) -> list[str]:
    """Warnings in words: N > 50 τ per parameter, acceptance, ensembles' agreement."""
    out = []
    for r in runs:
        n = r.chain.shape[0]
        bad = [
            f"{nm} (τ {t:.0f})"
            for nm, t in zip(names, r.tau, strict=True)
            if not (np.isfinite(t) and n > 50 * t)
        ]
        if bad:
            out.append(
                f"{r.name}: {n} steps are not more than 50 τ for "
                f"{', '.join(bad)}: run longer (--resume --steps N) before trusting "
                "the intervals"
            )
        acc = float(np.mean(r.acceptance))
        lo, hi, expected = ACCEPTANCE.get(r.moves, ACCEPTANCE["stretch"])
        if not lo <= acc <= hi:
            out.append(
                f"{r.name}: acceptance {acc:.2f} (expected {expected} with --moves {r.moves})"
            )
    return out
