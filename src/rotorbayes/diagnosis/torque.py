"""Beyond the catalogue: the missing-torque map.

With the fitted parameters and the *measured* angles (smoothed derivatives), each disc's
equation of motion should balance.  What is left over is the torque the model lacks:

    M_l = J_l θl'' + T_fl(ωl) + k_alpha α + c_alpha α'                      (lower disc)
    M_u = J_u θu'' + T_fu(ωu) − k_alpha α − c_alpha α' − k_m v(t)             (upper disc)

(friction levels shifted and torques added by user effects included).  Only samples in
clear slip are used: at rest friction is set-valued and balances anything.

The map ranks how much of ``M`` each candidate variable explains (adjusted R² of a
binned-mean or harmonic fit): the disc's velocity and its direction, its angle within a
revolution (once to eight times per revolution), the string's torsion and its rate, the input
and its rate, time.

What the map can support.  Smoothed derivatives of quantised angles are not exact: the
same balance computed on the fit's own simulation, rounded like the encoders, is not zero
either.  So the map is the data's balance *minus* the simulation's (sample by sample, on
the same slip samples), which removes what the derivatives and the model share, and its
**noise level** is what rounding alone does to a balance (the RMS difference of the
simulation's balance with and without rounding).  A map whose RMS is within that noise
(at most :data:`WITHIN_NOISE` times it) shows no missing torque; above it, the words report
a missing torque with its ratio to the noise.  They name a dependence only when the
torque's RMS is at least :data:`NOISE_FACTOR` times the noise, the explained part
(``sqrt(R²) * RMS``) is too, ``R²`` is at least :data:`MIN_R2`, and it beats every other
variable clearly (by :data:`DISTINCT_R2` in R², or leaving at most half of the next best's
unexplained part); variables that move together in the data — speed, direction, input —
are otherwise named together, as such.  A missing torque that no variable explains is
said to be so, naming the variables.

What the catalogue can test of a named dependence is :data:`TESTED_BY`: the diagnosis
weighs the map's words against those effects' score tests in one place
(:func:`rotorbayes.diagnosis.diagnose.map_agreement`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..inference.problem import Problem
from ..inference.starts import derivatives, slip_mask
from ..model.friction import friction_curve

#: The harmonics of a disc's angle the map tries: once to eight times per revolution (an
#: eccentric or uneven surface, an oval contact, a motor's or gear's cogging, rolling
#: elements or bolts around the shaft).  A cogging torque four times per revolution hidden
#: in reference data was read as "the string's torsion" when the map tried only the first
#: two.
ANGLE_HARMONICS = (1, 2, 3, 4, 5, 6, 7, 8)
#: The map's variables of those harmonics (``angle_h``).
ANGLE_VARIABLES = tuple(f"angle_{h}" for h in ANGLE_HARMONICS)


def harmonic_of(variable: str) -> int:
    """``h`` of an angle variable ``angle_h``."""
    return int(variable.split("_", 1)[1])


def _times_per_rev(h: int) -> str:
    return {1: "once", 2: "twice"}.get(h, f"{h} times")


def _angle_words() -> dict[str, tuple[str, str]]:
    causes = {
        1: "friction or load varying with angle (an eccentric or uneven bearing or brake surface)",
        2: "friction or load varying with angle (an oval or misaligned contact)",
    }
    return {
        f"angle_{h}": (
            f"varies with its angle, {_times_per_rev(h)} per revolution",
            causes.get(
                h,
                f"a torque that repeats {h} times a revolution (cogging of a motor or a "
                "gear, rolling elements, bolts or poles around the shaft)",
            ),
        )
        for h in ANGLE_HARMONICS
    }


#: Words for a dependence: (what varies, what usually causes it).
WORDS = {
    "velocity": (
        "varies with its speed",
        "a friction law unlike the model's (viscous or Stribeck part, or their asymmetry)",
    ),
    "direction": (
        "depends on the direction of rotation",
        "friction that differs between the two directions (asymmetric Coulomb or viscous friction)",
    ),
    **_angle_words(),
    "torsion": (
        "varies with the string's torsion",
        "a string stiffness that is not "
        "linear, or damping in the string (a fit without it bends the stiffness "
        "to take part of it)",
    ),
    "torsion_rate": (
        "varies with the rate of the string's twist",
        "damping in the string (string_damping)",
    ),
    "input": (
        "varies with the input voltage",
        "a motor constant, offset or dead zone unlike the model's",
    ),
    "input_rate": (
        "follows changes of the input",
        "a delay or dynamics between the command and the motor torque",
    ),
    "input_history": (
        "follows the input's recent history (the input low-pass filtered "
        "over 10-200 ms, against the input itself)",
        "a lag between the command and the motor torque (the amplifier's "
        "and the motor's electrical dynamics), not a pure delay",
    ),
    "time": (
        "drifts with time within the run",
        "slow changes: a friction level that "
        "warms up or wears (it changes sign with the motion), or a drifting load or "
        "sensor",
    ),
}

#: Time constants [s] of the low-pass filtered inputs the map's input-history variable
#: uses: a lag of the drive between them is a combination of their differences from the
#: input.
HISTORY_TAUS = (0.01, 0.04, 0.16)

#: Short names of the variables, for a list.
SHORT = {
    "velocity": "its speed",
    "direction": "the direction of rotation",
    **{v: f"its angle ({_times_per_rev(harmonic_of(v))} per revolution)" for v in ANGLE_VARIABLES},
    "torsion": "the string's torsion",
    "torsion_rate": "the twist rate",
    "input": "the input voltage",
    "input_rate": "the input's rate",
    "input_history": "the input's recent history",
    "time": "time",
}

#: The catalogue's version of each dependence's usual cause: per disc, the effects whose
#: score tests test what :data:`WORDS` names, and what else the dependence can be when
#: none of those tests supports it.  Angle and time have none (no catalogue effect
#: produces them).  :func:`rotorbayes.diagnosis.diagnose.map_agreement` is the one place
#: that weighs a map's words against these tests.
TESTED_BY: dict[str, tuple[dict[str, tuple[str, ...]], str]] = {
    "velocity": (
        {
            "l": ("lower_stribeck", "lower_asymmetric_viscous", "lower_asymmetric_coulomb"),
            "u": ("upper_stribeck", "upper_asymmetric_viscous", "upper_asymmetric_coulomb"),
        },
        "a friction law of another shape than the catalogue's",
    ),
    "direction": (
        {
            "l": ("lower_asymmetric_coulomb", "lower_asymmetric_viscous"),
            "u": ("upper_asymmetric_coulomb", "upper_asymmetric_viscous"),
        },
        "another torque that changes sign with the motion",
    ),
    "torsion": (
        {"l": ("string_damping",), "u": ("string_damping",)},
        "a string stiffness that is not linear (not in the catalogue)",
    ),
    "torsion_rate": (
        {"l": ("string_damping",), "u": ("string_damping",)},
        "damping of another form than the catalogue's",
    ),
    "input": (
        {"l": ("voltage_offset", "motor_deadzone"), "u": ("voltage_offset", "motor_deadzone")},
        "a motor nonlinearity the catalogue does not hold",
    ),
    "input_rate": (
        {"l": ("input_delay", "drive_lag"), "u": ("input_delay", "drive_lag")},
        "dynamics between the command and the motor torque other than a pure "
        "delay or a first-order lag (not in the catalogue)",
    ),
    "input_history": (
        {"l": ("drive_lag", "input_delay"), "u": ("drive_lag", "input_delay")},
        "drive dynamics of higher order than the catalogue's first-order lag",
    ),
}

#: A map whose RMS is at most this many times its noise shows no missing torque.  The
#: noise is what rounding alone does to a balance; a fit at the floor leaves less than
#: that (0.24-0.43x on the reference's controls, upper, coupled and brake), so a map above
#: it lacks a torque, however small.  (A map below :data:`NOISE_FACTOR` times its noise
#: used to read "no missing torque": one 2.4x its noise, at 318x the floor, did.)
WITHIN_NOISE = 1.0
#: The missing torque, and the part a dependence explains, must be this many times the
#: map's own noise before the words name what it depends on.
NOISE_FACTOR = 3.0
#: A dependence on a disc's angle within a revolution is looked for only if the disc
#: turned through at least this many revolutions (else the angle is just a slow trend).
MIN_TURNS = 2.0
#: Smallest adjusted R² of a dependence the words name.
MIN_R2 = 0.2
#: A dependence is named alone only if its R² beats every other variable's by this much,
DISTINCT_R2 = 0.2
#: ... or leaves at most 1/DISTINCT_RATIO of the unexplained part the next best leaves.
DISTINCT_RATIO = 2.0
#: Two variables "move together" only if at least this fraction of the weaker one's R²
#: is shared with the stronger one (what it adds beyond it is small): two dependences that
#: each explain a part of their own are not confused with one seen twice.
SHARED = 0.5
#: A disc's balance that its own terms' columns give to within this fraction of its
#: largest fitted term holds no own terms: it has no term of a fixed size (a geometric
#: inertia, a fixed motor constant), so its free parameters scaled alike balance it
#: whatever the data.  Such a balance is in their span to rounding (1e-9 here); one with
#: a fixed term leaves at least the derivatives' noise (1e-3).
OWN_SPAN = 1e-6


@dataclass
class TorqueMap:
    """The missing torque of one disc and what it depends on."""

    disc: str
    t: np.ndarray = field(repr=False)
    torque: np.ndarray = field(repr=False)
    features: dict[str, np.ndarray] = field(repr=False)
    ranking: list[tuple[str, float]]
    rms: float
    noise_rms: float
    #: Per variable: the part a map of rounding noise alone would seem to explain (RMS
    #: [N m]); a dependence is named only well above it (see :meth:`bar`).  Empty: the
    #: per-sample noise ``noise_rms`` is the bar (the stricter rule).
    null: dict[str, float] = field(default_factory=dict)
    #: Per variable: the fraction of its adjusted R² that the strongest variable's
    #: already holds (near 1: the two move together in the data; near 0: each explains
    #: its own part).  Empty: unknown, the R² rule alone decides.
    shared: dict[str, float] = field(default_factory=dict)
    #: Which run (experiment) each sample comes from; None: one run.  With several runs a
    #: constant of each run's own replaces the one constant in every regression (see
    #: :func:`run_offsets`).
    runs: np.ndarray | None = field(default=None, repr=False)
    #: The disc's own terms: the balance's derivatives by the free parameters at the fit,
    #: along the data (columns); every regression holds them, so a dependence is named
    #: only for what other values of the fitted parameters could not give.  None: the
    #: disc's balance has no term of a fixed size (see :data:`OWN_SPAN`), or no free
    #: parameter acts on it.
    own: np.ndarray | None = field(default=None, repr=False)
    #: The free parameters of those columns.
    own_names: tuple[str, ...] = ()
    #: Their fitted values.
    own_fitted: tuple[float, ...] = ()

    @property
    def base(self) -> np.ndarray | None:
        """The columns every regression of this map holds first (None: a constant)."""
        return _full_base(run_offsets(self.runs), self.own, self.torque.size)

    @functools.cached_property
    def _own_fit(self) -> tuple[np.ndarray, np.ndarray]:
        """The regression of the torque on :attr:`base` with the own terms: ``(base,
        coefficients)``, computed once (the words, the figure and the values use it)."""
        base = self.base
        assert base is not None and self.own is not None
        beta, *_ = np.linalg.lstsq(base, self.torque, rcond=None)
        return base, beta

    @functools.cached_property
    def _own_parts(self) -> tuple[float, float, np.ndarray]:
        """The own terms' adjusted R² (beyond the runs' constants), the RMS [N m] left
        beyond them and the constants, and what is left about the runs' constants."""
        if self.own is None:
            return 0.0, self._run_parts[1], self.torque
        base, beta = self._own_fit
        left = self.torque - base @ beta
        # What is left, about the runs' own constants (the own columns and the constants
        # can be collinear -- an initial torsion's column is a constant -- so the own
        # columns' coefficients alone mean nothing).
        runs = run_offsets(self.runs)
        if runs is None:
            level = np.full_like(left, self.torque.mean())
        else:
            gamma, *_ = np.linalg.lstsq(runs, self.torque, rcond=None)
            level = runs @ gamma
        return (
            _adj_r2(self.torque, base, runs),
            float(np.sqrt(np.mean(left**2))),
            left + level,
        )

    @property
    def rest_rms(self) -> float:
        """RMS [N m] left beyond the own terms and the runs' constants (within the runs
        where the map holds no own terms)."""
        return self._own_parts[1]

    @property
    def beyond_own(self) -> np.ndarray:
        """The missing torque less what other values of the fitted parameters would give
        (the torque itself where the map holds no own terms): what the figure draws."""
        return self._own_parts[2]

    @property
    def strongest(self) -> tuple[str, float] | None:
        return self.ranking[0] if self.ranking else None

    @functools.cached_property
    def _run_parts(self) -> tuple[float, float]:
        """RMS [N m] of the runs' own constants about their common mean, and of what is
        left within the runs (0 and the whole RMS for one run); computed once."""
        base = run_offsets(self.runs)
        if base is None:
            return 0.0, self.rms
        beta, *_ = np.linalg.lstsq(base, self.torque, rcond=None)
        fitted = base @ beta
        return (
            float(np.sqrt(np.mean((fitted - self.torque.mean()) ** 2))),
            float(np.sqrt(np.mean((self.torque - fitted) ** 2))),
        )

    @property
    def _scale(self) -> float:
        """The RMS a dependence's R² is a fraction of: the whole map for one run, what is
        left within the runs for several (the regressions hold each run's constant), what
        is left beyond the own terms too where the map holds them."""
        if self.own is not None:
            return self._own_parts[1]
        return self.rms if self.runs is None else self._run_parts[1]

    @property
    def own_r2(self) -> float:
        """Adjusted R² of the own terms (0 without them)."""
        return self._own_parts[0]

    @property
    def own_notable(self) -> bool:
        """The own terms take a part of the torque worth saying: R² at least
        :data:`MIN_R2` and that part :data:`NOISE_FACTOR` times the map's noise."""
        between = self._run_parts[1] if self.runs is not None else self.rms
        return (
            self.own is not None
            and self.own_r2 >= MIN_R2
            and math.sqrt(self.own_r2) * between >= NOISE_FACTOR * self.noise_rms
        )

    @functools.cached_property
    def balance_values(self) -> dict[str, tuple[float, float]]:
        """Per own parameter the data's balance can tell from the others: ``(fitted, the
        balance's value)``, the value at which this disc's own terms take their part of
        the torque (an equation-error estimate from the measured angles, one disc; it
        takes part of a missing torque too).  Parameters whose column the other columns
        give (an asymmetry beside a level and the constant), or all but 1 % of it, are
        left out."""
        if self.own is None:
            return {}
        base, beta = self._own_fit
        k = self.own.shape[1]
        first = base.shape[1] - k
        out = {}
        for j, (name, fitted) in enumerate(zip(self.own_names, self.own_fitted, strict=True)):
            col = base[:, first + j]
            others = np.delete(base, first + j, axis=1)
            g, *_ = np.linalg.lstsq(others, col, rcond=None)
            apart_rms = float(np.sqrt(np.mean((col - others @ g) ** 2)))
            # Less than a hundredth of the column's own variation apart from the others:
            # its coefficient is not the data's (an asymmetry's column is the constant's
            # and the level's; near such, a value 1e6 times the fit's was printed).
            if apart_rms < 1e-2 * float(np.sqrt(np.mean(col**2))):
                continue
            out[name] = (fitted, fitted - float(beta[first + j]))
        return out

    @functools.cached_property
    def _balance_moves(self) -> list[tuple[float, str]]:
        """The own parameters of :attr:`balance_values` by the torque their change moves
        (RMS [N m] of the column times the change), largest first."""
        if self.own is None:
            return []
        idx = {n: j for j, n in enumerate(self.own_names)}
        moves = [
            (float(np.sqrt(np.mean(self.own[:, idx[n]] ** 2))) * abs(f - b), n)
            for n, (f, b) in self.balance_values.items()
        ]
        return sorted(moves, reverse=True)

    def _own_words(self) -> str:
        names = ", ".join(self.own_names)
        # The parameters whose change moves the most torque, while it is a tenth of the
        # map's noise or more.
        vals = self.balance_values
        values = "; ".join(
            f"{n} {vals[n][1]:.3g} for the fit's {vals[n][0]:.3g}"
            for size, n in self._balance_moves[: self.LISTED]
            if size >= 0.1 * self.noise_rms
        )
        at = f" (the balance alone puts {values})" if values else ""
        return (
            f"; {100 * self.own_r2:.0f} % of it is what this disc's own terms would give at "
            f"other values of the fitted {names}{at}: the fit bent them (for a torque "
            "missing elsewhere, which can be the other disc's), or it sits in another basin "
            "(a multistart, or a fit from the data, tells which)"
        )

    def _runs_words(self) -> str:
        """What the runs' own constants add to the words (nothing when they are small)."""
        between, _ = self._run_parts
        if between < NOISE_FACTOR * self.noise_rms:
            return ""
        return (
            f"; besides, each run is off by a constant of its own (RMS {between:.2g} N m "
            "between the runs, not read as a dependence): a start state that is off in "
            "some run (its initial torsion) or a load that changed between the runs"
        )

    @property
    def rms_over_noise(self) -> float:
        """The missing torque's RMS as a multiple of the map's noise."""
        return self.rms / self.noise_rms if self.noise_rms > 0 else math.inf

    @property
    def exceeds_noise(self) -> bool:
        """The map shows a missing torque: its RMS is above :data:`WITHIN_NOISE` times the
        map's noise (at or below it, rounding alone could make it)."""
        return self.rms > WITHIN_NOISE * self.noise_rms

    @property
    def above_noise(self) -> bool:
        """The missing torque is large enough (:data:`NOISE_FACTOR` times the map's
        noise) for the map to name what it depends on; where the map holds own terms,
        what is left beyond them."""
        left = self.rms if self.own is None else self._own_parts[1]
        return left >= NOISE_FACTOR * self.noise_rms

    @property
    def together(self) -> list[tuple[str, float]]:
        """The strongest dependence and every variable within :data:`DISTINCT_R2` of it."""
        s = self.strongest
        if s is None:
            return []
        # Another variable is as good if its R² is within DISTINCT_R2 of the best one's and
        # it leaves less than DISTINCT_RATIO times the best one's unexplained part.
        return [
            (k, v)
            for k, v in self.ranking
            if v >= s[1] - DISTINCT_R2
            and (1 - v) < DISTINCT_RATIO * max(1 - s[1], 1e-12)
            and (k == s[0] or self.shared.get(k, 1.0) >= SHARED)
        ]

    def bar(self, variable: str) -> float:
        """The explained RMS [N m] a dependence on ``variable`` must reach to be named:
        :data:`NOISE_FACTOR` times what rounding noise alone would seem to explain with
        the same regression on the same samples (the noise is correlated over the
        derivative filter's window, so this is larger than the white-noise value)."""
        return NOISE_FACTOR * self.null.get(variable, self.noise_rms)

    @property
    def supports_words(self) -> bool:
        """The map supports naming one dependence (above noise, clear, distinct)."""
        s = self.strongest
        return bool(
            s is not None
            and self.above_noise
            and s[1] >= MIN_R2
            and math.sqrt(max(s[1], 0.0)) * self._scale >= self.bar(s[0])
            and len(self.together) == 1
        )

    def variables(self) -> str:
        """The map's candidate variables in words: "its speed, ... or time"."""
        keys = [k for k in SHORT if k in self.features] or [
            k for k in SHORT if k in dict(self.ranking)
        ]
        names = []
        for k in keys:
            name = "its angle within a revolution" if k.startswith("angle_") else SHORT[k]
            if name not in names:
                names.append(name)
        if len(names) < 2:
            return "".join(names) or "the candidate variables"
        return ", ".join(names[:-1]) + " or " + names[-1]

    def words(self) -> str:
        text = self._words()
        return text + self._runs_words() if self.exceeds_noise else text

    #: At most this many variables are listed as alike; the rest are counted.
    LISTED = 4

    def _together_words(self) -> str:
        """The variables as good as the strongest, with their R²: four at most, the rest
        counted (a map of noise had fourteen alike at 0.21-0.22, one after the other)."""
        items = [f"{SHORT[k]} (adjusted R² {v:.2f})" for k, v in self.together]
        if len(items) > self.LISTED:
            rest = len(items) - (self.LISTED - 1)
            items = [*items[: self.LISTED - 1], f"and {rest} more variables alike"]
        return ", ".join(items)

    def _words(self) -> str:
        disc = "upper" if self.disc == "u" else "lower"
        noise = f"the map's noise {self.noise_rms:.2g} N m"
        ratio = _times(self.rms_over_noise, WITHIN_NOISE)
        if not self.exceeds_noise:
            return (
                f"the {disc} disc's map shows no missing torque beyond its noise (RMS "
                f"{self.rms:.2g} N m, {ratio}x {noise}: within it)"
            )
        head = (
            f"the {disc} disc lacks a torque {ratio}x the map's noise (RMS "
            f"{self.rms:.2g} N m, {noise})"
        )
        of_it = "of it"
        if self.own_notable:
            head += self._own_words()
            left = self._own_parts[1]
            if left < NOISE_FACTOR * self.noise_rms:
                return (
                    f"{head}; what is left beyond them (RMS {left:.2g} N m) is below "
                    f"{NOISE_FACTOR:g}x the map's noise: nothing of its own to name here"
                )
            head += f"; beyond them, the rest (RMS {left:.2g} N m)"
            of_it = "of the rest"
        s = self.strongest
        if s is None or s[1] < MIN_R2:
            # (Naming "the best" at an adjusted R² of 0.00 read as a finding.)
            best = (
                f"; the best, {SHORT[s[0]]}, at {s[1]:.2f}"
                if s is not None and s[1] >= 0.01
                else ""
            )
            return (
                f"{head} that none of {self.variables()} explains (no clear dependence: "
                f"no adjusted R² reaches {MIN_R2:g}{best}): a torque these variables do "
                "not describe, or several missing torques at once"
            )
        explained = math.sqrt(max(s[1], 0.0)) * self._scale
        if explained < self.bar(s[0]):
            # The best candidate is worth a look, but its part is not clearly above what
            # noise alone would explain: say so, as a hint (no claim).
            best = self._together_words()
            what = (
                "the map's noise"
                if s[0] not in self.null
                else "what rounding noise alone seems to explain"
            )
            return (
                f"{head}; the best candidate, {best}, explains {explained:.2g} N m of "
                f"it, below {NOISE_FACTOR:g}x {what}: a hint to look at in "
                "missing_torque.png, not a finding"
            )
        if not self.above_noise:
            best = self._together_words()
            return (
                f"{head}; the best candidate, {best}, explains {explained:.2g} N m of "
                f"it, but the torque is below {NOISE_FACTOR:g}x the map's noise, the bar "
                "for naming what it depends on: a hint to look at in missing_torque.png, "
                "not a finding"
            )
        if len(self.together) > 1:
            names = self._together_words()
            return (
                f"{head} that varies with several variables alike: {names}; they move "
                "together in these data, so the map cannot tell which"
            )
        what, cause = WORDS[s[0]]
        also = [
            k
            for k, v in self.ranking[1:]
            if v >= MIN_R2
            and k not in dict(self.together)
            and self.shared.get(k, 1.0) < SHARED
            and math.sqrt(v) * self._scale >= self.bar(k)
        ]
        # One harmonic of the angle stands for the angle (a stiffening string's map
        # listed all eight beside the torsion, one after the other).
        angles = [k for k in also if k.startswith("angle_")]
        skip = set(angles[1:]) | (set(angles) if s[0].startswith("angle_") else set())
        also = [k for k in also if k not in skip]
        more = (
            f"; apart from it, also with {', '.join(SHORT[k] for k in also)} (each "
            "explains a part of its own)"
            if also
            else ""
        )
        return (
            f"{head} that {what} (explains {100 * s[1]:.0f} % {of_it}): {cause}"
            f"{self._angle_words(s[0])}{more}"
        )

    def angle_terms(self, variable: str) -> dict | None:
        """For a dependence on angle (``angle_1`` ... ``angle_8``): the two parts the map's
        regression separates, as a user effect would write them, with ``theta`` the disc's
        angle and ``s`` its direction of rotation:

        * ``friction``: extra friction against the motion, ``A cos(h (theta - phi))``
          (the missing torque is ``-s`` times it);
        * ``load``: a torque alike in both directions, ``A cos(h (theta - phi))``.

        Each as ``{"amplitude": A [N m], "phase": phi [rad], "harmonic": h}``; the constant
        and direction columns (a Coulomb level, an asymmetry) are left out."""
        if not variable.startswith("angle_") or variable not in self.features:
            return None
        X = _design(variable, self.features, self.base)
        if X is None or X.shape[0] <= X.shape[1]:
            return None
        beta, *_ = np.linalg.lstsq(X, self.torque, rcond=None)
        h = harmonic_of(variable)
        out = {}
        # columns: the constant(s), s, sin, cos, s sin, s cos
        for name, (a, b, sign) in (
            ("load", (beta[-4], beta[-3], 1.0)),
            ("friction", (beta[-2], beta[-1], -1.0)),
        ):
            a, b = sign * a, sign * b
            out[name] = {
                "amplitude": float(math.hypot(a, b)),
                "phase": float(math.atan2(a, b) / h),
                "harmonic": h,
            }
        return out

    def _angle_words(self, variable: str) -> str:
        terms = self.angle_terms(variable)
        if not terms:
            return ""
        f, ld = terms["friction"], terms["load"]
        th = "theta_l" if self.disc == "l" else "theta_u"
        h = f["harmonic"]
        main, other = (
            (("friction", f), ("load", ld))
            if f["amplitude"] >= ld["amplitude"]
            else (("load", ld), ("friction", f))
        )
        # theta - phi with its sign written once ("theta_l + 1.57", not "theta_l - -1.57")
        phi = main[1]["phase"]
        shift = f"{th} - {phi:.3g}" if phi >= 0 else f"{th} + {-phi:.3g}"
        arg = shift if h == 1 else f"{h}*({shift})"
        what = {
            "friction": "extra friction against the motion",
            "load": "a torque alike in both directions (a load)",
        }
        return (
            f"; its form: mostly {what[main[0]]}, {main[1]['amplitude']:.2g}*cos({arg}) N m, "
            f"beside {other[0]} of amplitude "
            f"{other[1]['amplitude']:.2g} N m (a start for your own effect, "
            "docs/effects.md)"
        )

    def as_dict(self) -> dict:
        terms = {k: self.angle_terms(k) for k, _ in self.ranking if k.startswith("angle_")}
        return {
            "disc": self.disc,
            "rms_N_m": self.rms,
            "noise_rms_N_m": self.noise_rms,
            "rms_over_noise": self.rms_over_noise,
            "between_runs_rms_N_m": self._run_parts[0],
            "own_terms": None
            if self.own is None
            else {
                "parameters": list(self.own_names),
                "adjusted_r2": self.own_r2,
                "rest_rms_N_m": self._own_parts[1],
                "balance_values": {
                    n: {"fitted": f, "balance": b} for n, (f, b) in self.balance_values.items()
                },
            },
            "exceeds_noise": self.exceeds_noise,
            "angle_terms": {k: v for k, v in terms.items() if v},
            "above_noise": self.above_noise,
            "supports_words": self.supports_words,
            "ranking": [
                {
                    "variable": k,
                    "adjusted_r2": v,
                    "noise_explains_N_m": self.null.get(k),
                    "shared_with_strongest": self.shared.get(k),
                }
                for k, v in self.ranking
            ],
            "words": self.words(),
        }


def apart(a: float, b: float, digits: int = 3) -> tuple[str, str]:
    """``a`` and ``b`` in the fewest significant digits (at least ``digits``) that keep
    their order: 17.09 and 17.2 read "17.1" and "17.2", 17.09 and 17.1 "17.09" and "17.1"
    (never two equal numbers for two different values)."""
    for d in range(digits, 12):
        sa, sb = f"{a:.{d}g}", f"{b:.{d}g}"
        fa, fb = float(sa), float(sb)
        if (fa < fb) == (a < b) and (fa > fb) == (a > b):
            return sa, sb
    return repr(a), repr(b)


def _times(ratio: float, threshold: float) -> str:
    """``ratio`` in two significant digits, or more where two would put it on the other
    side of ``threshold`` (1.004 reads "1.004", not "1")."""
    return apart(ratio, threshold, 2)[0] if math.isfinite(ratio) else "inf"


def run_offsets(runs: np.ndarray | None) -> np.ndarray | None:
    """Indicator columns of the runs, or None for one run.

    Runs that start from different states (a string wound before the run, each with its
    own fitted initial torsion) leave each run's missing torque off by a constant of its
    own where that state is off.  Those constants are not a dependence on any variable:
    with one constant per run in every regression, a variable that merely differs between
    runs (the input's level, time across records) is not named for them."""
    if runs is None:
        return None
    ids, idx = np.unique(runs, return_inverse=True)
    return None if ids.size < 2 else _indicators(idx)


def _indicators(idx: np.ndarray) -> np.ndarray:
    """One column per value of the integer labels ``idx`` (0, 1, ...): 1 where it holds."""
    X = np.zeros((idx.size, int(idx.max()) + 1))
    X[np.arange(idx.size), idx] = 1.0
    return X


def _residual_ss(y: np.ndarray, base: np.ndarray | None) -> tuple[float, int]:
    """Sum of squares of ``y`` about its mean (``base`` None) or about its least squares
    on ``base``'s columns, and the columns used."""
    if base is None:
        return float(np.sum((y - y.mean()) ** 2)), 1
    beta, *_ = np.linalg.lstsq(base, y, rcond=None)
    return float(np.sum((y - base @ beta) ** 2)), base.shape[1]


def _adj_r2(y: np.ndarray, X: np.ndarray, base: np.ndarray | None = None) -> float:
    """Adjusted R² of ``y`` on ``X``, measured against what ``base`` (a constant, or one
    per run) explains alone; ``X`` holds ``base``'s columns."""
    n, k = X.shape
    if n <= k + 1:
        return math.nan
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    ss = float(np.sum((y - X @ beta) ** 2))
    st, k0 = _residual_ss(y, base)
    if st <= 0:
        return 0.0
    return 1 - (ss / (n - k)) / (st / (n - k0))


def _binned(x: np.ndarray, n_bins: int = 16) -> np.ndarray:
    """Indicator columns of quantile bins of ``x``."""
    edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(len(edges) - 2, 0))
    return _indicators(idx)


def _design(
    k: str, feats: dict[str, np.ndarray], base: np.ndarray | None = None
) -> np.ndarray | None:
    """The regression columns of a dependence on variable ``k`` (None: it never varies);
    ``base``: the constant's columns (default one; :func:`run_offsets` for several runs),
    first."""
    v = feats[k]
    one = np.ones((len(v), 1)) if base is None else base
    if k == "direction":
        return np.column_stack([one, v])
    if k.startswith("angle_"):
        # A load varying with angle acts alike in both directions; a friction level
        # varying with angle acts against the motion: both columns, with the sign.
        h = harmonic_of(k)
        s = feats["direction"]
        return np.column_stack(
            [one, s, np.sin(h * v), np.cos(h * v), s * np.sin(h * v), s * np.cos(h * v)]
        )
    if k == "time":
        # A drift is a trend, not any function of time (which would explain everything):
        # of a load (the same in both directions) or of a friction level (against the
        # motion, so with the direction's sign).  No column of the direction alone: a
        # constant asymmetry is the direction's, not a drift.
        tt = (v - v.mean()) / max(np.ptp(v), 1e-12)
        s = feats["direction"]
        return np.column_stack([one, tt, tt**2, s * tt, s * tt**2])
    if k == "input_history":
        # The filtered inputs' differences from the input (columns), linear: a lag.
        return np.column_stack([one, v])
    if np.ptp(v) == 0:
        return None
    # The bins hold a constant; the runs' own constants beside them (one column too many,
    # which least squares does not mind).
    return _binned(v) if base is None else np.column_stack([base, _binned(v)])


def _rank(
    M: np.ndarray, feats: dict[str, np.ndarray], base: np.ndarray | None = None
) -> list[tuple[str, float]]:
    out = []
    for k in feats:
        X = _design(k, feats, base)
        if X is not None:
            out.append((k, _adj_r2(M, X, base)))
    return sorted([o for o in out if math.isfinite(o[1])], key=lambda kv: -kv[1])


def _null_and_shared(
    M: np.ndarray,
    R: np.ndarray,
    feats: dict[str, np.ndarray],
    ranking: list[tuple[str, float]],
    base: np.ndarray | None = None,
) -> tuple[dict, dict]:
    """What rounding noise alone seems to explain per variable, and how much of each
    variable's R² the strongest one already holds (see :class:`TorqueMap`).

    The noise: the same regression on ``R`` (the balance of the fit's simulation with
    rounding minus without; the map subtracts two such roundings, hence sqrt 2), by its
    plain R², never less than white noise's sqrt(columns / samples)."""
    null: dict[str, float] = {}
    shared: dict[str, float] = {}
    r_rms = float(np.sqrt(np.mean(R**2)))
    st, _ = _residual_ss(R, base)
    n = R.size
    top = ranking[0] if ranking else None
    X_top = _design(top[0], feats, base) if top else None
    for k, r2 in ranking:
        X = _design(k, feats, base)
        beta, *_ = np.linalg.lstsq(X, R, rcond=None)
        r2_noise = 1.0 - float(np.sum((R - X @ beta) ** 2)) / st if st > 0 else 0.0
        white = math.sqrt(X.shape[1] / max(n, 1))
        null[k] = math.sqrt(2.0) * r_rms * max(math.sqrt(max(r2_noise, 0.0)), white)
        if top is not None and k != top[0] and r2 > 0:
            joint = _adj_r2(M, np.column_stack([X_top, X]), base)
            shared[k] = float(min(max((top[1] + r2 - joint) / r2, 0.0), 1.0))
    return null, shared


def missing_torque(
    problem: Problem,
    x: np.ndarray,
    *,
    window: float = 0.1,
    seed: int = 0,
    floors: dict | None = None,
) -> list[TorqueMap]:
    """The missing-torque maps of the discs the problem models (lower, then upper).

    The map of each disc is the data's balance minus that of the fit's own simulation
    rounded like the encoders (and with the data's extra noise, if the floor says they
    have some); its noise level is what rounding alone does to a balance.  ``floors``:
    the noise floor per channel (default :meth:`Problem.noise_floors`).
    """
    from ..io.measurements import (
        LOWER_COUNTS_PER_REV,
        UPPER_COUNTS_PER_REV,
        quantisation_floor,
        quantize,
    )

    rng = np.random.default_rng(seed)
    if floors is None:
        floors, _ = problem.noise_floors()
    maps = {"l": [], "u": []}
    for i, ex in enumerate(problem.experiments):
        p = problem.params_for(x, i)
        sim = problem.simulate(x, i)
        sim_thl = sim.theta_l if ex.theta_l is not None else None

        def rounded(theta, channel, counts):
            extra = math.sqrt(
                max(floors.get(channel, 0.0) ** 2 - quantisation_floor(channel) ** 2, 0.0)
            )
            th = theta + extra * rng.standard_normal(theta.size) if extra > 0 else theta
            return quantize(th, counts)

        given = _kinematics(ex, ex.theta_u, ex.theta_l, window)
        given = (given, _user_torques(problem, ex, p, given))
        data = _balance(problem, ex, p, ex.theta_u, ex.theta_l, window, given=given)
        own = _own_columns(problem, x, i, ex, data, window, given)
        model_q = _balance(
            problem,
            ex,
            p,
            rounded(sim.theta_u, "theta_u", UPPER_COUNTS_PER_REV),
            None if sim_thl is None else rounded(sim_thl, "theta_l", LOWER_COUNTS_PER_REV),
            window,
        )
        model_x = _balance(problem, ex, p, sim.theta_u, sim_thl, window)
        for disc in ("l", "u"):
            if disc not in data:
                continue
            t, M, feats, sel = data[disc]
            # In clear slip in the fit's simulation too: where it sticks, or turns slowly,
            # its balance is no balance (friction at rest balances anything), and its
            # rounded angles' derivatives jump; a fit far from the data (1071x the floor)
            # had such samples raise the map's noise 4-30 fold, and a clear angle
            # dependence read as "a hint".
            sel = sel & model_x[disc][3]
            Mq = model_q[disc][1]
            Mx = model_x[disc][1]
            maps[disc].append(
                (
                    t[sel],
                    (M - Mq)[sel],
                    {k: v[sel] for k, v in feats.items()},
                    (Mq - Mx)[sel],
                    own[disc][0][sel],
                    own[disc][1][sel],
                )
            )
    out = []
    for disc in ("l", "u"):
        parts = maps[disc]
        if not parts or sum(len(pt[0]) for pt in parts) < 50:
            continue
        T = np.concatenate([pt[0] for pt in parts])
        M = np.concatenate([pt[1] for pt in parts])
        keys = [k for k in parts[0][2] if all(k in pt[2] for pt in parts)]
        F = {k: np.concatenate([pt[2][k] for pt in parts]) for k in keys}
        R = np.concatenate([pt[3] for pt in parts])
        runs = np.concatenate([np.full(len(pt[0]), i) for i, pt in enumerate(parts)])
        own, own_names = _own_terms(
            np.vstack([pt[4] for pt in parts]), np.concatenate([pt[5] for pt in parts]), x
        )
        names = tuple(problem.names[k] for k in own_names)
        base = _full_base(run_offsets(runs), own, M.size)
        # What rounding alone does to a balance: the map cannot resolve less.
        noise = float(np.sqrt(np.mean(R**2)))
        ranking = _rank(M, F, base)
        null, shared = _null_and_shared(M, R, F, ranking, base)
        out.append(
            TorqueMap(
                disc,
                T,
                M,
                F,
                ranking,
                float(np.sqrt(np.mean(M**2))),
                noise,
                null,
                shared,
                runs=runs if run_offsets(runs) is not None else None,
                own=own,
                own_names=names,
                own_fitted=tuple(float(x[k]) for k in own_names),
            )
        )
    return out


def _balance(
    problem: Problem,
    ex,
    p: dict,
    theta_u,
    theta_l,
    window: float,
    *,
    given=None,
    features: bool = True,
) -> dict:
    """Each disc's torque balance from the angles ``theta_u``/``theta_l`` (smoothed
    derivatives) at parameters ``p``: ``{disc: (t, M, features, slip mask)}``, the mask
    and features taken from these angles' own velocities.

    ``given``: the angles' derivatives and the user effects' torques from an earlier call
    (:func:`_kinematics`, :func:`_user_torques`), for the same angles at other parameters
    (the own-term columns of :func:`_own_columns`: user effects' torques held);
    ``features`` False: the balances alone (empty features, no mask)."""
    m = problem.model
    if given is None:
        kin = _kinematics(ex, theta_u, theta_l, window)
        hooked = _user_torques(problem, ex, p, kin)
    else:
        kin, hooked = given
    thu, wu, au, thl, wl, al, n = kin
    t = ex.t
    u = ex.u
    v = _voltage(u, t, p)
    has_l = theta_l is not None
    if has_l:
        alpha = thl - thu + p.get("alpha0", 0.0)
        dalpha = wl - wu
    else:
        alpha = dalpha = np.zeros_like(thu)
    c_alpha = p.get("c_alpha", 0.0) if "c_alpha" in m.active else 0.0
    string = p.get("k_alpha", 0.0) * alpha + c_alpha * dalpha if has_l else 0.0
    extra_u, extra_l, shift_u, shift_l = hooked
    common = (
        {
            "input": v,
            "input_rate": np.gradient(u, ex.dt),
            "input_history": _history(v, ex.dt),
            "time": t,
        }
        if features
        else {}
    )
    out: dict[str, tuple] = {}
    if has_l and m.configuration.has_lower:
        pl = _complete(p)
        if m.replacing is not None:  # its law gives the dry friction (in extra_l): viscous
            pl = {**pl, "Tc_l": 0.0, "dTc_l": 0.0, "Ts_l": 0.0}
        fl = np.nan_to_num(friction_curve(wl, pl, "l", shape=problem.shape))
        Ml = p["J_l"] * al + fl + np.sign(wl) * shift_l + string - extra_l
        if not features:
            out["l"] = (t, Ml, {}, None)
        else:
            feats = {
                "velocity": wl,
                "direction": np.sign(wl),
                "torsion": alpha,
                "torsion_rate": dalpha,
                **common,
            }
            if np.ptp(thl) >= MIN_TURNS * 2 * np.pi:
                feats.update(dict.fromkeys(ANGLE_VARIABLES, np.mod(thl, 2 * np.pi)))
            out["l"] = (t, Ml, feats, slip_mask(wl, n, 0.02))
    if not problem.prescribed_upper:
        fu = np.nan_to_num(friction_curve(wu, _complete(p), "u", shape=problem.shape))
        Mu = p["J_u"] * au + fu + np.sign(wu) * shift_u - string - p["k_m"] * v - extra_u
        if not features:
            out["u"] = (t, Mu, {}, None)
            return out
        feats = {"velocity": wu, "direction": np.sign(wu), **common}
        if np.ptp(thu) >= MIN_TURNS * 2 * np.pi:
            feats.update(dict.fromkeys(ANGLE_VARIABLES, np.mod(thu, 2 * np.pi)))
        if has_l:
            feats["torsion"] = alpha
            feats["torsion_rate"] = dalpha
        out["u"] = (t, Mu, feats, slip_mask(wu, n, 0.02))
    return out


def _own_columns(problem: Problem, x: np.ndarray, i: int, ex, data: dict, window, given):
    """Per disc, the balance's derivatives by each free parameter at ``x`` along the data's
    angles (columns in the order of ``x``; a user effect's parameters give zero columns,
    its torque held) and the balance itself: ``{disc: (D, B)}``."""
    cols: dict[str, list] = {d: [] for d in data}
    for k in range(x.size):
        h = 1e-6 * max(abs(float(x[k])), 1e-3)
        xk = x.copy()
        xk[k] += h
        pk = problem.params_for(xk, i)
        bk = _balance(problem, ex, pk, ex.theta_u, ex.theta_l, window, given=given, features=False)
        for d in data:
            cols[d].append((bk[d][1] - data[d][1]) / h)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for d in data:
        D = np.column_stack(cols[d]) if cols[d] else np.zeros((data[d][1].size, 0))
        out[d] = (D, data[d][1])
    return out


def _own_terms(D: np.ndarray, B: np.ndarray, x: np.ndarray) -> tuple[np.ndarray | None, list]:
    """The own-term columns a disc's map holds (see :class:`TorqueMap`), and their indices
    in ``x``; ``(None, [])`` where they give the disc's balance ``B`` itself (to
    :data:`OWN_SPAN` of its largest fitted term): the balance has no term of a fixed size,
    every parameter of it scaled alike balances it too, and its own terms would take any
    missing torque whatever.  (Not Euler's sum ``D x``: an initial torsion's product with
    the stiffness counts twice in it.)"""
    keep = [k for k in range(D.shape[1]) if np.any(D[:, k] != 0)]
    if not keep:
        return None, []
    Dk = D[:, keep]
    sizes = np.sqrt(np.mean((Dk * x[keep]) ** 2, axis=0))
    g, *_ = np.linalg.lstsq(Dk, B, rcond=None)
    if float(np.sqrt(np.mean((B - Dk @ g) ** 2))) < OWN_SPAN * float(np.max(sizes)):
        return None, []
    return Dk, keep


def _full_base(runs: np.ndarray | None, own: np.ndarray | None, n: int) -> np.ndarray | None:
    """The columns every regression of a map holds first: a constant (one per run with
    several runs) and the disc's own terms, if any (None: the constant alone)."""
    if own is None:
        return runs
    return np.column_stack([np.ones((n, 1)) if runs is None else runs, own])


def _kinematics(ex, theta_u, theta_l, window: float) -> tuple:
    """Smoothed angles, velocities and accelerations of both discs (zeros for a lower disc
    without data) and the filter's length."""
    thu, wu, au, n = derivatives(theta_u, ex.dt, window)
    if theta_l is not None:
        thl, wl, al, _ = derivatives(theta_l, ex.dt, window)
    else:
        thl = wl = al = np.zeros_like(thu)
    return thu, wu, au, thl, wl, al, n


def _user_torques(problem: Problem, ex, p: dict, kin: tuple) -> tuple:
    """The user effects' torques and friction shifts along the angles ``kin``:
    ``(extra_u, extra_l, shift_u, shift_l)`` (zeros without user effects)."""
    m = problem.model
    use, hook_t, hook_s, hook_r, _ = m.hooks()
    thu, wu, _, thl, wl, _, _ = kin
    t = ex.t
    dt = ex.dt
    extra_u = np.zeros_like(t)
    extra_l = np.zeros_like(t)
    shift_u = np.zeros_like(t)
    shift_l = np.zeros_like(t)
    if not use:
        return extra_u, extra_l, shift_u, shift_l
    v = _voltage(ex.u, t, p)
    pv, qv = m.kernel_vectors(p)
    # A stateful effect's state along these angles: its rate integrated sample by
    # sample (trapezoidal; good enough for a map of what is missing).
    z = 0.0
    for k in range(t.size):
        args = (t[k], thu[k], wu[k], thl[k], wl[k], v[k])
        a_u, a_l = hook_t(*args, z, pv, qv)
        s_u, s_l = hook_s(*args, z, pv, qv)
        extra_u[k], extra_l[k] = a_u, a_l
        shift_u[k], shift_l[k] = s_u, s_l
        if m.stateful is not None and k + 1 < t.size:
            r0 = hook_r(*args, z, pv, qv)[0]
            e = 1e-7 * (abs(z) + 1e-3)
            lam = -(hook_r(*args, z + e, pv, qv)[0] - r0) / e
            if dt * lam > 0.5:  # a stiff state (bristles): linearly implicit
                z += dt * r0 / (1.0 + dt * lam)
                continue
            nxt = (t[k + 1], thu[k + 1], wu[k + 1], thl[k + 1], wl[k + 1], v[k + 1])
            r1 = hook_r(*nxt, z + dt * r0, pv, qv)[0]
            z += 0.5 * dt * (r0 + r1)
    return extra_u, extra_l, shift_u, shift_l


def _history(v: np.ndarray, dt: float) -> np.ndarray:
    """Columns: the input low-pass filtered at each of :data:`HISTORY_TAUS` (first order,
    exact for a held sample, starting from the held first value), minus the input."""
    from ..util.smoothing import lowpass

    cols = []
    for tau in HISTORY_TAUS:
        cols.append(lowpass(v, math.exp(-dt / tau)) - v)
    return np.column_stack(cols)


def _complete(p: dict) -> dict:
    q = dict(p)
    for k in ("dTc_l", "db_l", "dTc_u", "db_u"):
        q[k] = q.get(k, 0.0) if q.get(k) is not None else 0.0
    return q


def _voltage(u: np.ndarray, t: np.ndarray, p: dict) -> np.ndarray:
    """The effective motor voltage (lag, delay, offset, dead zone) at the sample times: the
    kernel's own (:func:`rotorbayes.kernel.terms.voltage_at`, held at ``u[0]`` before the
    first sample), not a copy of it."""
    from ..kernel.layout import CFG_COUPLED, NAMES
    from ..kernel.terms import voltage_at

    pv = np.array([float(p.get(n, 0.0) or 0.0) for n in NAMES])
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    return voltage_at(np.arange(t.size) * dt, np.ascontiguousarray(u, float), pv, dt, CFG_COUPLED)
