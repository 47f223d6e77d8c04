"""The one module that knows which arviz line is installed; nothing else imports arviz.

arviz has two lines. 0.2x (the last served to Python 3.11) keeps the groups of a posterior
in :class:`arviz.InferenceData` and computes the diagnostics itself; 1.x (Python >= 3.12)
keeps them in xarray's :class:`xarray.DataTree`, with the converters in arviz-base and the
statistics in arviz-stats. Everything rotorbayes needs from either goes through the few
functions here, so both lines give the same file (``posterior.nc``: one netCDF group per
arviz group, written with h5netcdf) and the same summary columns:

* :func:`from_groups` builds the container from plain arrays, one xarray Dataset per group;
* :func:`group` returns a group as an :class:`xarray.Dataset`, :func:`group_names` their names;
* :func:`to_bytes` makes ``posterior.nc``'s content in memory, :func:`save` writes it and
  :func:`load` reads it (fully into memory; a file that cannot be read as a posterior raises
  :class:`PosteriorFileError`, never the HDF5 library's own error);
* :func:`summary` gives mean, sd, HDI (``hdi_low``/``hdi_high``), bulk and tail ESS, R-hat
  and the Monte-Carlo standard errors under the same column names on both lines.
"""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path

import numpy as np

#: netCDF engine for posterior.nc on both lines (h5netcdf is a dependency of rotorbayes).
ENGINE = "h5netcdf"

#: Dimensions of every draw-wise group.
SAMPLE_DIMS = ("chain", "draw")

_AZ = None


def arviz():
    """The installed arviz module, imported once.

    arviz 0.2x announces its 1.x refactor with a FutureWarning on import (once a day);
    the refactor is what this module is for, so the notice is not passed on to the user.
    """
    global _AZ
    if _AZ is None:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning, module=r"arviz.*")
            warnings.filterwarnings(
                "ignore", message=r".*ArviZ is undergoing a major refactor", category=FutureWarning
            )
            import arviz as az
        _AZ = az
    return _AZ


def version() -> str:
    """The installed arviz's version string."""
    return str(arviz().__version__)


def is_datatree_line() -> bool:
    """True for arviz 1.x (DataTree, arviz-base, arviz-stats), False for 0.2x."""
    return int(version().split(".")[0]) >= 1


def _dataset(variables: dict, dims: dict, coords: dict, sample: bool, attrs: dict | None):
    import xarray as xr

    data_vars, used = {}, {}
    for name, value in variables.items():
        a = np.asarray(value)
        extra = list(dims.get(name, []))
        lead = list(SAMPLE_DIMS) if sample else []
        n_free = a.ndim - len(lead) - len(extra)
        if n_free < 0:
            raise ValueError(
                f"{name}: {a.ndim} dimensions, fewer than the "
                f"{len(lead) + len(extra)} named ({lead + extra})"
            )
        extra += [f"{name}_dim_{i}" for i in range(n_free)]
        all_dims = lead + extra
        data_vars[name] = (all_dims, a)
        for d, size in zip(all_dims, a.shape, strict=True):
            if d in coords:
                used[d] = np.asarray(coords[d])
            elif d in SAMPLE_DIMS:
                used[d] = np.arange(size)
    return xr.Dataset(data_vars, coords=used, attrs=dict(attrs or {}))


def from_groups(
    groups: dict[str, dict[str, np.ndarray]],
    *,
    dims: dict | None = None,
    coords: dict | None = None,
    attrs: dict[str, dict] | None = None,
):
    """The posterior container of the installed arviz line.

    Parameters
    ----------
    groups : dict
        Group name (``posterior``, ``sample_stats``, ``log_likelihood``,
        ``posterior_predictive``, ``observed_data``, ``constant_data``) to variables. The
        draw-wise groups' arrays are ``(chain, draw, ...)``; the data groups' have no
        sample dimensions.
    dims : dict, optional
        Per group, variable name to the names of its dimensions after (chain, draw).
    coords : dict, optional
        Dimension name to coordinate values (shared by all groups).
    attrs : dict, optional
        Per group, attributes to store with it.

    Returns
    -------
    arviz.InferenceData (arviz 0.2x) or xarray.DataTree (arviz 1.x)
    """
    dims, coords, attrs = dims or {}, coords or {}, attrs or {}
    sets = {}
    for g, variables in groups.items():
        sample = g not in ("observed_data", "constant_data")
        sets[g] = _dataset(variables, dims.get(g, {}), coords, sample, attrs.get(g))
    az = arviz()
    if is_datatree_line():
        import xarray as xr

        return xr.DataTree.from_dict(sets)
    return az.InferenceData(**sets)


def group_names(idata) -> list[str]:
    """Names of the groups present (``posterior``, ``sample_stats``, ...)."""
    if is_datatree_line():
        return [str(k) for k in idata.children]
    return list(idata.groups())


def group(idata, name: str):
    """One group as an :class:`xarray.Dataset`; KeyError when it is absent."""
    if name not in group_names(idata):
        raise KeyError(f"the posterior has no {name} group (it has {group_names(idata)})")
    if is_datatree_line():
        return idata[name].to_dataset()
    return getattr(idata, name)


class PosteriorFileError(ValueError):
    """A posterior file cannot be read: damaged (truncated, overwritten), empty, or not a
    ``posterior.nc`` written by rotorbayes.  The message names the file and what failed."""


def _compressible(dtype) -> bool:
    return np.dtype(dtype).kind in "biufc"


def to_bytes(idata) -> memoryview:
    """``posterior.nc``'s content, made in memory: one netCDF group per arviz group
    (zlib-compressed numbers), the same file on both lines.

    Made in memory so that the disk is touched only by plain writes of these bytes (into
    room reserved beforehand, in ``rotorbayes sample``): a disk that fills up can then end
    a write with an ordinary error, never inside the HDF5 library with files half open.
    """
    import io

    buf = io.BytesIO()
    mode = "w"
    for name in group_names(idata):
        ds = group(idata, name)
        enc = {v: {"zlib": True} for v, x in ds.variables.items() if _compressible(x.dtype)}
        ds.to_netcdf(buf, mode=mode, group=name, engine=ENGINE, encoding=enc)
        mode = "a"
    return buf.getbuffer()


def save(idata, path: str | Path) -> None:
    """Write ``idata`` to a netCDF file with one group per arviz group (:func:`to_bytes`)."""
    data = to_bytes(idata)
    with open(path, "wb") as fh:
        fh.write(data)


def load(path: str | Path):
    """Read a posterior file written by :func:`save` (by either arviz line) into memory;
    the file is closed on return.

    A file that is missing, empty, truncated, overwritten or holds no ``posterior`` group
    raises :class:`PosteriorFileError` naming it and what failed.
    """
    path = Path(path)
    failure = None
    with _quiet_teardown():
        try:
            if path.is_dir():
                raise IsADirectoryError(f"{path} is a folder")
            if path.exists() and path.stat().st_size == 0:
                raise ValueError("the file is empty (0 bytes)")
            idata = _load(path)
        except Exception as exc:  # noqa: BLE001 - h5py, h5netcdf, xarray: OSError, KeyError...
            failure = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
    if failure is not None:  # raised here, without the library's frames (and open objects)
        raise PosteriorFileError(
            f"{path}: cannot be read as a posterior ({failure}): damaged (truncated or "
            "overwritten?), or not a posterior.nc written by `rotorbayes sample`"
        )
    if "posterior" not in group_names(idata):
        raise PosteriorFileError(
            f"{path}: holds no posterior group (it has "
            f"{', '.join(group_names(idata)) or 'no group'}): not a "
            "posterior.nc written by `rotorbayes sample`"
        )
    return idata


@contextlib.contextmanager
def _quiet_teardown():
    """The block's half-opened netCDF objects go quietly: h5netcdf's ``File.__del__`` of a
    file that failed to open raises, which Python prints as "Exception ignored in ..." with a
    traceback; the damaged file is reported in words instead."""
    import gc
    import sys

    old = sys.unraisablehook

    def hook(unraisable) -> None:
        where = getattr(unraisable.object, "__module__", None) or ""
        if not where.startswith(("h5netcdf", "h5py", "xarray")):
            old(unraisable)

    sys.unraisablehook = hook
    try:
        yield
        gc.collect()
    finally:
        sys.unraisablehook = old


def _load(path: Path):
    if is_datatree_line():
        import xarray as xr

        with xr.open_datatree(path, engine=ENGINE) as tree:
            return tree.load().copy()
    az = arviz()
    idata = az.from_netcdf(str(path), engine=ENGINE)
    for g in idata.groups():
        getattr(idata, g).load()
        getattr(idata, g).close()
    return idata


#: The columns of :func:`summary`, the same on both lines.
SUMMARY_COLUMNS = (
    "mean",
    "sd",
    "hdi_low",
    "hdi_high",
    "ess_bulk",
    "ess_tail",
    "r_hat",
    "mcse_mean",
    "mcse_sd",
)


def summary(idata, var_names: list[str] | None = None, hdi_prob: float = 0.94):
    """Posterior summary as a :class:`pandas.DataFrame` indexed by variable.

    Columns: :data:`SUMMARY_COLUMNS` — mean, sd, the ``hdi_prob`` highest-density interval
    (``hdi_low``, ``hdi_high``), arviz's rank-normalised bulk and tail ESS, split R-hat
    across chains, and the Monte-Carlo standard errors of the mean and sd. Unrounded.
    """
    az = arviz()
    with warnings.catch_warnings():
        # R-hat and ESS of a one-chain or very short posterior are undefined (NaN in the
        # table); arviz says so with a RuntimeWarning the table already conveys.
        warnings.simplefilter("ignore", RuntimeWarning)
        if is_datatree_line():
            s = az.summary(
                idata,
                var_names=var_names,
                kind="all",
                ci_prob=hdi_prob,
                ci_kind="hdi",
                round_to="none",
            )
        else:
            s = az.summary(
                idata, var_names=var_names, kind="all", hdi_prob=hdi_prob, round_to="none"
            )
    # The interval's two columns, lower first: hdi_3%, hdi_97% (0.2x); hdi94_lb, hdi94_ub (1.x).
    lo_c, hi_c = [c for c in s.columns if str(c).startswith("hdi")]
    s = s.rename(columns={lo_c: "hdi_low", hi_c: "hdi_high"})
    return s.loc[:, list(SUMMARY_COLUMNS)].astype(float)
