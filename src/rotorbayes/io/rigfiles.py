"""How to read a rig's own files: which of its names are the model's columns, in what units,
and the MATLAB ``.mat`` files (v5 and v7.3) a Simulink-driven rig records.

A measurement needs four signals: the time ``t`` [s], the motor voltage ``u`` [V] and the
two disc angles ``theta_u``, ``theta_l`` [rad].  A rig's logger names them as it likes
(``Time``, ``Volt``, ``ScopeData.signals(2).values(:,1)``) and writes time in s or ms and
angles in rad, degrees or encoder counts.  A :class:`ReadSpec` says all of that once;
:func:`rotorbayes.io.measurements.load_experiment` reads with it, and a fit records it (fit.json's
``data_files[i].read``) so that every later command reads the file the same way.

Names in a ``.mat`` file
------------------------
A name is a MATLAB expression on the file's variables: ``Time`` (a variable),
``ScopeData.time`` (a field of a struct), ``ScopeData.signals(2).values`` (the second
element of a struct array, 1-based as in MATLAB) and ``data(:,3)`` or ``data(3,:)`` (a
column or a row of a matrix).  Vectors may be stored as rows or columns (1xN or Nx1).
Simulink's "Structure With Time" (``ScopeData.time``, ``ScopeData.signals.values``) and
"Array" (one matrix, a column per signal) formats are both reached this way.  Without a
mapping a file must hold variables named ``t``, ``u``, ``theta_u`` (and ``theta_l``).

Conversions (exactly these, so a converted file fits bit for bit like the original)
--------------------------------------------------------------------------------------
* time in ms: ``t_s = t_ms / 1000``;
* angles in degrees: ``theta = deg * (pi / 180)``;
* angles in counts: ``theta = counts * (2 pi / counts_per_rev)``, with the counts per
  revolution of each encoder (default the rig's: 54 934.256 upper, 40 000 lower).
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ReadSpec",
    "FormatProblem",
    "SIGNALS",
    "TIME_UNITS",
    "ANGLE_UNITS",
    "DEFAULT_COUNTS_PER_REV",
    "is_mat_file",
    "read_mat",
    "parse_number",
]

#: The model's signals, as a mapping names them.
SIGNALS = ("t", "u", "theta_u", "theta_l")
#: Units a time column may be declared in, with their factor to seconds (division).
TIME_UNITS = {"s": 1.0, "ms": 1000.0}
#: Units the angle columns may be declared in.
ANGLE_UNITS = ("rad", "deg", "counts")
#: The rig's encoders (thesis §2.2): counts per revolution of each disc.
DEFAULT_COUNTS_PER_REV = {"theta_u": 54934.256, "theta_l": 40000.0}

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_NAME = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*(?:\(([^()]*)\))?\s*$")


class FormatProblem(ValueError):
    """A file's layout or a mapping that cannot be used; the caller adds the file's name."""


@dataclass(frozen=True)
class ReadSpec:
    """How to read a measurement file: the file's names of the model's signals and the
    units it holds them in.

    Parameters
    ----------
    columns : mapping of str to str, optional
        The file's name of each signal: ``{"t": "Time", "u": "Volt", "theta_u": "Enc1"}``.
        A signal not named is looked for under its own name.  With a mapping, the file's
        other columns are ignored.
    time_unit : {"s", "ms"}
        Unit of the time column.
    angle_unit : {"rad", "deg", "counts"}
        Unit of both angle columns.
    counts_per_rev : mapping of str to float, optional
        Encoder counts per revolution by channel, for ``angle_unit="counts"`` (default:
        the rig's encoders, :data:`DEFAULT_COUNTS_PER_REV`).
    """

    columns: Mapping[str, str] = field(default_factory=dict)
    time_unit: str = "s"
    angle_unit: str = "rad"
    counts_per_rev: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        cols = dict(self.columns or {})
        bad = [k for k in cols if k not in SIGNALS]
        if bad:
            raise FormatProblem(
                f"columns: {bad[0]!r} is not a signal of the model; map "
                f"{', '.join(SIGNALS)} (e.g. t=Time,u=Volt)"
            )
        for k, v in cols.items():
            if not isinstance(v, str) or not v.strip():
                raise FormatProblem(f"columns: {k} = {v!r}; give the file's name of {k}")
        object.__setattr__(self, "columns", {k: cols[k].strip() for k in SIGNALS if k in cols})
        if self.time_unit not in TIME_UNITS:
            raise FormatProblem(f"time unit {self.time_unit!r}: choose s or ms")
        if self.angle_unit not in ANGLE_UNITS:
            raise FormatProblem(f"angle unit {self.angle_unit!r}: choose rad, deg or counts")
        cpr = dict(self.counts_per_rev or {})
        for k, v in cpr.items():
            if k not in DEFAULT_COUNTS_PER_REV:
                raise FormatProblem(
                    f"counts per revolution: {k!r} is not an angle; give theta_u=N and/or theta_l=N"
                )
            if (
                isinstance(v, bool)
                or not isinstance(v, int | float)
                or not (math.isfinite(v) and 1 <= v <= 1e9)
            ):
                raise FormatProblem(
                    f"counts per revolution of {k}: {v!r}; give the encoder's "
                    "counts per revolution, a number from 1 to 1e9"
                )
        object.__setattr__(
            self, "counts_per_rev", {k: float(cpr[k]) for k in DEFAULT_COUNTS_PER_REV if k in cpr}
        )
        if self.counts_per_rev and self.angle_unit != "counts":
            raise FormatProblem(
                f"counts per revolution given, but the angles are read in "
                f"{self.angle_unit}; they are for --angle-unit counts "
                '(analysis file: angle_unit = "counts")'
            )

    # -- construction from the command line, an analysis file, a fit.json ----------------

    @classmethod
    def from_options(
        cls,
        columns=None,
        time_unit: str | None = None,
        angle_unit: str | None = None,
        counts_per_rev=None,
    ) -> ReadSpec:
        """From the options' forms: ``columns`` as ``"t=Time,u=data(:,2)"`` or a mapping,
        ``counts_per_rev`` as ``"theta_u=N,theta_l=N"``, one number for both, or a mapping."""
        return cls(
            parse_columns(columns),
            time_unit or "s",
            angle_unit or "rad",
            parse_counts(counts_per_rev),
        )

    @classmethod
    def from_record(cls, rec) -> ReadSpec:
        """From :meth:`as_dict` (fit.json); an absent record is the default."""
        if rec is None:
            return cls()
        if not isinstance(rec, Mapping):
            raise FormatProblem(f"the recorded way of reading, {rec!r}, is not a table")
        return cls(
            rec.get("columns") or {},
            rec.get("time_unit", "s"),
            rec.get("angle_unit", "rad"),
            rec.get("counts_per_rev") or {},
        )

    def as_dict(self) -> dict:
        """The spec as JSON (for fit.json)."""
        return {
            "columns": dict(self.columns),
            "time_unit": self.time_unit,
            "angle_unit": self.angle_unit,
            "counts_per_rev": dict(self.counts_per_rev),
        }

    @property
    def is_default(self) -> bool:
        """No mapping and SI units: the plain measurement CSV."""
        return not self.columns and self.time_unit == "s" and self.angle_unit == "rad"

    def options(self) -> str:
        """The command-line options that give this spec (empty for the default)."""
        out = []
        if self.columns:
            out.append("--columns " + ",".join(f"{k}={v}" for k, v in self.columns.items()))
        if self.time_unit != "s":
            out.append(f"--time-unit {self.time_unit}")
        if self.angle_unit != "rad":
            out.append(f"--angle-unit {self.angle_unit}")
        if self.counts_per_rev:
            out.append(
                "--counts-per-rev " + ",".join(f"{k}={v:g}" for k, v in self.counts_per_rev.items())
            )
        return " ".join(out)

    def name_of(self, signal: str) -> str:
        """The file's name of ``signal``."""
        return self.columns.get(signal, signal)

    def cpr(self, channel: str) -> float:
        """Counts per revolution of ``channel``'s encoder."""
        return self.counts_per_rev.get(channel, DEFAULT_COUNTS_PER_REV[channel])

    def to_si(self, cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The signals in s, V and rad (the conversions of the module docstring)."""
        out = dict(cols)
        if self.time_unit != "s" and "t" in out:
            out["t"] = out["t"] / TIME_UNITS[self.time_unit]
        for ch in DEFAULT_COUNTS_PER_REV:
            if ch not in out:
                continue
            if self.angle_unit == "deg":
                out[ch] = out[ch] * (math.pi / 180.0)
            elif self.angle_unit == "counts":
                out[ch] = out[ch] * (2.0 * math.pi / self.cpr(ch))
            # A resting encoder reads 0.0, never -0.0.
            out[ch] = out[ch] + 0.0
        return out


def _split_top(text: str) -> list[str]:
    """``text`` split at the commas outside parentheses (``data(:,1),x`` is two items)."""
    items, depth, cur = [], 0, []
    for ch in text:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        if ch == "," and depth == 0:
            items.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    items.append("".join(cur))
    return [i.strip() for i in items if i.strip()]


def parse_columns(spec) -> dict[str, str]:
    """``"t=Time,u=Volt"`` (or a mapping) as a mapping of signals to the file's names."""
    if spec is None or spec == "":
        return {}
    if isinstance(spec, Mapping):
        return {str(k).strip(): v for k, v in spec.items()}
    out: dict[str, str] = {}
    for item in _split_top(str(spec)):
        key, sep, name = item.partition("=")
        key = key.strip()
        if not sep or not name.strip():
            raise FormatProblem(
                f"columns: {item!r} is not SIGNAL=NAME; write e.g. "
                "t=Time,u=Volt,theta_u=Enc1,theta_l=Enc2"
            )
        if key in out:
            raise FormatProblem(f"columns: {key} is mapped twice; map each signal once")
        out[key] = name.strip()
    return out


def parse_counts(spec) -> dict[str, float]:
    """``"theta_u=N,theta_l=N"``, one number for both encoders, or a mapping."""
    if spec is None or spec == "":
        return {}
    if isinstance(spec, Mapping):
        return dict(spec)
    if isinstance(spec, int | float) and not isinstance(spec, bool):
        return {k: float(spec) for k in DEFAULT_COUNTS_PER_REV}
    text = str(spec).strip()
    try:
        v = float(text)
    except ValueError:
        pass
    else:
        return {k: v for k in DEFAULT_COUNTS_PER_REV}
    out: dict[str, float] = {}
    for item in _split_top(text):
        key, sep, num = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[key.strip()] = float(num)
        except ValueError:
            raise FormatProblem(
                f"counts per revolution: {item!r} is not CHANNEL=NUMBER; "
                "write e.g. theta_u=54934.256,theta_l=40000 (or one number "
                "for both encoders)"
            ) from None
    return out


def parse_number(text: str, decimal_comma: bool) -> float:
    """A number of a CSV field; with ``decimal_comma`` a comma is the decimal mark."""
    if decimal_comma:
        text = text.replace(",", ".")
    return float(text)


# --------------------------------------------------------------------------------------------
# MATLAB files


def is_mat_file(head: bytes, suffix: str) -> bool:
    """Whether a file starting with ``head`` (its first 520 bytes or more) is a MATLAB
    file: the text header of v5/v7.3, an HDF5 file (at 0, or after the 512-byte header
    of v7.3), or a ``.mat`` name."""
    return (
        head.startswith(b"MATLAB")
        or head.startswith(_HDF5_SIGNATURE)
        or head[512:520] == _HDF5_SIGNATURE
        or suffix.lower() == ".mat"
    )


def read_mat(data: bytes, spec: ReadSpec, wanted: tuple[str, ...]) -> tuple[dict, dict]:
    """The signals ``wanted`` (model names; ``theta_l`` only if the file has it) from the
    bytes of a MATLAB file, as float64 vectors in the file's units, and the file's name of
    each.  :class:`FormatProblem` says what is missing and what the file holds."""
    tree = _mat_tree(data)
    cols, names = {}, {}
    for sig in wanted:
        name = spec.name_of(sig)
        optional = sig == "theta_l" and sig not in spec.columns
        try:
            node = _lookup(tree, name)
        except KeyError:
            if optional:
                continue
            raise FormatProblem(_missing(tree, sig, name, spec)) from None
        cols[sig] = _vector(node, name)
        names[sig] = name
    n = {k: v.size for k, v in cols.items()}
    if len(set(n.values())) > 1:
        raise FormatProblem(
            "the signals have different lengths ("
            + ", ".join(f"{k} = {names[k]}: {v}" for k, v in n.items())
            + "); map signals of one record"
        )
    return cols, names


def _mat_tree(data: bytes):
    """The variables of a MATLAB file as nested dicts (structs), lists (struct arrays and
    cells), strings and 2-D arrays in MATLAB's orientation (rows x columns)."""
    if data.startswith(_HDF5_SIGNATURE) or data[512:520] == _HDF5_SIGNATURE:
        return _h5_tree(data)
    import scipy.io

    try:
        raw = scipy.io.loadmat(
            io.BytesIO(data), squeeze_me=False, struct_as_record=True, chars_as_strings=True
        )
    except NotImplementedError as exc:  # scipy's answer to a v7.3 file it cannot read
        raise FormatProblem(
            f"a MATLAB file scipy cannot read ({exc}); save it again with save -v7 or -v7.3"
        ) from None
    except Exception as exc:  # noqa: BLE001 - any parser failure is a damaged file
        head = data[:512]
        text = (
            bool(head)
            and not data.startswith(b"MATLAB")
            and all(32 <= b < 127 or b in b"\t\r\n" for b in head)
        )
        raise FormatProblem(
            f"not a readable MATLAB file ({type(exc).__name__}: {exc}); "
            + (
                "it holds text: if it is a CSV file, name it .csv"
                if text
                else "save it again from MATLAB, or export CSV"
            )
        ) from None
    try:
        return {k: _v5(v) for k, v in raw.items() if not k.startswith("__")}
    except RecursionError:
        raise FormatProblem(
            "its structs are nested too deep to read; save the signals as plain variables"
        ) from None


@dataclass(frozen=True)
class _Object:
    """A MATLAB object (timeseries, Simulink.SimulationData.Dataset, a function handle):
    its data cannot be read outside MATLAB."""

    cls: str


def _v5(x):
    from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque

    if isinstance(x, MatlabOpaque | MatlabFunction):
        return _Object(str(getattr(x, "classname", "") or "opaque"))
    if isinstance(x, MatlabObject):
        return _Object(str(getattr(x, "classname", "") or "object"))
    if isinstance(x, np.ndarray):
        if x.dtype.names:  # a struct (array)
            elems = [{f: _v5(e[f]) for f in x.dtype.names} for e in x.ravel(order="F")]
            return elems[0] if len(elems) == 1 else elems
        if x.dtype == object:  # a cell array
            return [_v5(e) for e in x.ravel(order="F")]
        if x.dtype.kind in "US":
            return "".join(str(s) for s in x.ravel())
        if x.ndim == 1:
            x = x[None, :]
        return x
    return x


def _h5_tree(data: bytes):
    import h5py

    try:
        f = h5py.File(io.BytesIO(data), "r")
    except Exception as exc:  # noqa: BLE001 - any parser failure is a damaged file
        raise FormatProblem(
            f"not a readable MATLAB v7.3 (HDF5) file ({exc}); save it again "
            "from MATLAB, or export CSV"
        ) from None
    with f:
        try:
            return {k: _h5(f, f[k]) for k in f if not k.startswith("#")}
        except FormatProblem:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged file, or one nested absurdly
            raise FormatProblem(
                f"not a readable MATLAB v7.3 file ({type(exc).__name__}: "
                f"{exc}); save it again from MATLAB, or export CSV"
            ) from None


# The MATLAB classes of v7.3 datasets that hold data (others are objects' handles).
_H5_DATA_CLASSES = {
    "",
    "double",
    "single",
    "int8",
    "uint8",
    "int16",
    "uint16",
    "int32",
    "uint32",
    "int64",
    "uint64",
    "logical",
    "char",
    "cell",
    "struct",
}


def _h5(f, node):
    import h5py

    cls = node.attrs.get("MATLAB_class", b"")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
    if isinstance(node, h5py.Group):
        fields = {k: node[k] for k in node if not k.startswith("#")}
        refs = [
            d for d in fields.values() if isinstance(d, h5py.Dataset) and d.dtype == h5py.ref_dtype
        ]
        # A struct array: every field a dataset of references of one shape, one per element.
        if (
            fields
            and len(refs) == len(fields)
            and len({d.shape for d in refs}) == 1
            and refs[0].size > 1
        ):
            n = refs[0].size
            flat = {k: np.asarray(d).T.ravel(order="F") for k, d in fields.items()}
            return [{k: _h5(f, f[flat[k][i]]) for k in fields} for i in range(n)]
        return {k: _h5(f, d) for k, d in fields.items()}
    if node.attrs.get("MATLAB_empty", 0):
        return np.zeros((0, 0))
    if "MATLAB_object_decode" in node.attrs or cls not in _H5_DATA_CLASSES:
        return _Object(cls or "unknown")
    arr = np.asarray(node)
    if node.dtype == h5py.ref_dtype:  # a cell array
        return [_h5(f, f[r]) for r in arr.T.ravel(order="F")]
    if cls == "char":
        return "".join(map(chr, arr.ravel(order="C")))
    if arr.ndim == 1:
        arr = arr[None, :]
    return arr.T  # HDF5 holds MATLAB's column-major array with its axes reversed


def _lookup(tree, name: str):
    """The node ``name`` (``a.b(2).c(:,1)``) names; KeyError with what is there."""
    node = tree
    for part in name.split("."):
        m = _NAME.match(part)
        if m is None:
            raise FormatProblem(
                f"{name!r} is not a MATLAB name; write e.g. Time, "
                "ScopeData.time, ScopeData.signals(2).values or data(:,3)"
            )
        key, index = m.group(1).strip(), m.group(2)
        if not isinstance(node, dict) or key not in node:
            raise KeyError(name)
        node = node[key]
        if index is not None:
            node = _index(node, index.strip(), name)
    return node


def _index(node, index: str, name: str):
    parts = [p.strip() for p in index.split(",")]
    if len(parts) == 1:
        k = _one_based(parts[0], name)
        if isinstance(node, list):
            if not 1 <= k <= len(node):
                raise FormatProblem(f"{name}: element {k} of {len(node)}")
            return node[k - 1]
        if isinstance(node, dict) and k == 1:
            return node
        if isinstance(node, np.ndarray) and 1 <= k and node.ndim == 2 and min(node.shape) == 1:
            return node.ravel()[k - 1 : k]
        raise FormatProblem(
            f"{name}: ({parts[0]}) picks an element of a struct array; "
            "for a matrix write (:,COLUMN) or (ROW,:)"
        )
    if len(parts) != 2 or not isinstance(node, np.ndarray) or node.ndim != 2:
        raise FormatProblem(f"{name}: ({index}) indexes a matrix; write (:,COLUMN) or (ROW,:)")
    rows, cols = node.shape
    if parts[0] == ":":
        j = _one_based(parts[1], name)
        if not 1 <= j <= cols:
            raise FormatProblem(f"{name}: the matrix has {cols} column(s) ({rows}x{cols})")
        return node[:, j - 1 : j]
    if parts[1] == ":":
        i = _one_based(parts[0], name)
        if not 1 <= i <= rows:
            raise FormatProblem(f"{name}: the matrix has {rows} row(s) ({rows}x{cols})")
        return node[i - 1 : i, :]
    raise FormatProblem(f"{name}: ({index}) picks one number; write (:,COLUMN) or (ROW,:)")


def _one_based(text: str, name: str) -> int:
    try:
        k = int(text)
    except ValueError:
        raise FormatProblem(
            f"{name}: index {text!r} is not a whole number (MATLAB's indices start at 1)"
        ) from None
    if k < 1:
        raise FormatProblem(f"{name}: index {k}; MATLAB's indices start at 1")
    return k


def _vector(node, name: str) -> np.ndarray:
    if isinstance(node, np.ndarray) and node.dtype.kind in "biuf":
        if node.ndim == 2 and min(node.shape) == 1 or node.ndim <= 1:
            return np.ascontiguousarray(node.ravel(), dtype=np.float64)
        raise FormatProblem(
            f"{name} is a {node.shape[0]}x{node.shape[1]} matrix, not one "
            f"signal; pick a column with {name}(:,K) (or a row with "
            f"{name}(K,:))"
        )
    if isinstance(node, _Object):
        raise FormatProblem(
            f"{name} is a MATLAB object of class {node.cls}, whose data only MATLAB can "
            "read; save its arrays in the file instead (for a timeseries ts: "
            "t = ts.Time, u = ts.Data; Simulink's To Workspace block: the formats "
            "'Structure With Time' or 'Array')"
        )
    what = (
        "a struct (fields " + ", ".join(node) + ")"
        if isinstance(node, dict)
        else f"a list of {len(node)}"
        if isinstance(node, list)
        else "text"
        if isinstance(node, str)
        else f"of type {type(node).__name__}"
    )
    raise FormatProblem(
        f"{name} is {what}, not a vector of numbers; name the signal "
        "itself (e.g. ScopeData.signals(1).values)"
    )


def _listing(tree, prefix: str = "", out=None, depth: int = 0) -> list[str]:
    """``name (rows x cols)`` of the numeric arrays in ``tree``, for messages."""
    out = [] if out is None else out
    if depth > 4 or len(out) > 12:
        return out
    if isinstance(tree, dict):
        for k, v in tree.items():
            _listing(v, f"{prefix}.{k}" if prefix else k, out, depth + 1)
    elif isinstance(tree, list):
        for i, v in enumerate(tree[:4], start=1):
            if isinstance(v, dict):
                _listing(v, f"{prefix}({i})", out, depth + 1)
    elif isinstance(tree, np.ndarray) and tree.dtype.kind in "biuf" and tree.ndim == 2:
        out.append(f"{prefix} ({tree.shape[0]}x{tree.shape[1]})")
    elif isinstance(tree, _Object):
        out.append(f"{prefix} (a MATLAB {tree.cls} object: save its arrays instead)")
    return out


def _missing(tree, sig: str, name: str, spec: ReadSpec) -> str:
    held = ", ".join(_listing(tree)) or "no numeric variables"
    if sig in spec.columns:
        return f"no {name!r} for {sig} (--columns {sig}={name}); the file holds {held}"
    return (
        f"no variable {sig!r}: name the file's signals with --columns "
        "t=NAME,u=NAME,theta_u=NAME,theta_l=NAME (analysis file: columns = {t = "
        '"NAME", ...}), each NAME a variable, a struct\'s field (ScopeData.time, '
        "ScopeData.signals(2).values) or a matrix's column (Encoder(:,1)); the file "
        f"holds {held}"
    )
