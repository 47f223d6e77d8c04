"""Figures: labels, units, legends and the data they draw (issue 7, section 6)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from rotorbayes.figures import plots  # noqa: E402
from rotorbayes.io.measurements import quantisation_floor  # noqa: E402
from rotorbayes.model.parameters import resolve  # noqa: E402


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def legend_texts(ax) -> list[str]:
    leg = ax.get_legend()
    assert leg is not None, "no legend drawn on this axis"
    return [t.get_text() for t in leg.get_texts()]


def text_boxes(fig):
    """Window extents of every visible label, title and tick label, by owner."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    out = []
    if fig._suptitle is not None:
        out.append(("suptitle", fig._suptitle.get_window_extent(r)))
    for k, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison:
            continue
        texts = [ax.title, ax._left_title, ax.xaxis.label, ax.yaxis.label]
        for t in texts:
            if t.get_visible() and t.get_text():
                out.append((k, t.get_window_extent(r)))
        # tick labels that are drawn: those of ticks inside the view limits
        box = ax.get_window_extent(r)
        for t in ax.get_xticklabels():
            e = t.get_window_extent(r)
            if t.get_text() and box.x0 - 1 <= (e.x0 + e.x1) / 2 <= box.x1 + 1:
                out.append((k, e))
        for t in ax.get_yticklabels():
            e = t.get_window_extent(r)
            if t.get_text() and box.y0 - 1 <= (e.y0 + e.y1) / 2 <= box.y1 + 1:
                out.append((k, e))
    return out


def assert_no_overlap(fig):
    """No text of one axes (or the suptitle) overlaps a text of another."""
    boxes = text_boxes(fig)
    for i, (a, ba) in enumerate(boxes):
        for b, bb in boxes[i + 1 :]:
            if a != b and ba.overlaps(bb):
                raise AssertionError(f"texts of {a!r} and {b!r} overlap: {ba} vs {bb}")


def assert_inside(fig):
    """Every text and legend lies within the figure (nothing cut off at its edges)."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    page = fig.bbox
    items = [("suptitle", fig._suptitle)] if fig._suptitle is not None else []
    items += [("figure legend", leg) for leg in fig.legends]
    for k, ax in enumerate(fig.axes):
        items += [(k, t) for t in (ax.title, ax._left_title, ax.xaxis.label, ax.yaxis.label)]
        items += [(k, ax.yaxis.get_offset_text())]
        if ax.get_legend() is not None:
            items.append((k, ax.get_legend()))
        # tick labels that are drawn: those of ticks inside the view limits
        box = ax.get_window_extent(r)
        for t in ax.get_xticklabels():
            e = t.get_window_extent(r)
            if box.x0 - 1 <= (e.x0 + e.x1) / 2 <= box.x1 + 1:
                items.append((k, t))
        for t in ax.get_yticklabels():
            e = t.get_window_extent(r)
            if box.y0 - 1 <= (e.y0 + e.y1) / 2 <= box.y1 + 1:
                items.append((k, t))
    for who, a in items:
        if not a.get_visible() or (hasattr(a, "get_text") and not a.get_text()):
            continue
        e = a.get_window_extent(r)
        assert (
            e.x0 >= page.x0 - 0.5
            and e.x1 <= page.x1 + 0.5
            and e.y0 >= page.y0 - 0.5
            and e.y1 <= page.y1 + 0.5
        ), f"{who!r}: {a} at {e} is not inside the figure {page}"


# ---------------------------------------------------------------------- parameter spread
def test_parameter_spread_has_units_and_no_overlap():
    names = ["k_m", "Tc_u", "b_u", "dTc_u", "db_u", "alpha0[1]", "my_gain"]
    rng = np.random.default_rng(0)
    values = rng.normal(1.0, 0.1, size=(9, len(names)))
    ssr = np.r_[6.7e-6, 6.7e-6, 6.71e-6, 1e-3, 2e-2, 0.5, 3.0, 80.0, 1e4]
    fig, axes = plots.plot_parameter_spread(
        names,
        values,
        ssr,
        units={"my_gain": "N m/rad"},
        reference={"k_m": 1.0},
        noise_floor_ssr=6.5e-6,
        clusters=[0, 0, 0, 1, 2, 3, 4, 5, 6],
        title="multistart, upper: end points",
    )
    labels = [ax.get_xlabel() for ax in axes.ravel() if ax.axison]
    assert labels == [
        "k_m [N m/V]",
        "Tc_u [N m]",
        "b_u [N m s/rad]",
        "dTc_u [N m]",
        "db_u [N m s/rad]",
        "alpha0[1] [rad]",
        "my_gain [N m/rad]",
    ]
    assert all(ax.get_yscale() == "log" for ax in axes.ravel() if ax.axison)
    assert axes[0, 0].get_ylabel() == "final SSR [rad²]"
    # the y data are the absolute SSRs
    np.testing.assert_allclose(axes[0, 0].collections[0].get_offsets()[:, 1], ssr)
    assert fig._suptitle.get_text() == "multistart, upper: end points"
    leg = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("reference" in t for t in leg)
    assert any("encoder quantisation floor" in t for t in leg)
    assert_no_overlap(fig)
    assert_inside(fig)


def test_parameter_spread_units_from_registry_for_every_name():
    from rotorbayes.model.parameters import INFO

    assert plots.unit_of("alpha0[3]") == INFO["alpha0"].unit == "rad"
    assert plots.unit_of("delta_l") == "-"
    assert plots.unit_of("unknown_thing") == ""
    assert plots.unit_of("k_m", {"k_m": "mN m/V"}) == "mN m/V"


def test_parameter_spread_leaves_out_failed_and_says_so():
    fig, axes = plots.plot_parameter_spread(["k_m"], [[4.0], [5.0], [6.0]], [1.0, np.inf, 2.0])
    assert axes[0, 0].collections[0].get_offsets().shape[0] == 2
    assert "1 failed" in fig.legends[0].get_texts()[0].get_text()


# ---------------------------------------------------------------------------- waterfall
def test_waterfall_absolute_ssr_floor_and_failed_starts():
    ssr = np.array([3e-3, 6.7e-6, np.inf, 6.71e-6, 6.702e-6, np.nan, 12.0])
    floor = 6.54e-6
    fig, ax = plots.plot_waterfall(
        ssr, noise_floor_ssr=floor, n_failed=2, labels=[2, 0, 9, 0, 0, 9, 1]
    )
    finite = np.sort(ssr[np.isfinite(ssr)])
    ys = np.concatenate(
        [
            c.get_offsets()[:, 1]
            for c in ax.collections
            if c.get_label() and "failed" not in c.get_label()
        ]
    )
    np.testing.assert_allclose(np.sort(ys), finite)  # absolute, not relative to the best
    assert ys.min() == pytest.approx(6.7e-6)
    assert ax.get_yscale() == "log"
    assert ax.get_ylabel() == "final SSR [rad²]"
    lo, hi = ax.get_ylim()
    assert lo <= floor and hi >= finite.max()
    floor_lines = [ln for ln in ax.get_lines() if "floor" in ln.get_label()]
    assert len(floor_lines) == 1
    np.testing.assert_allclose(floor_lines[0].get_ydata(), floor)
    texts = legend_texts(ax)
    assert any(t.startswith("3 of 9 starts within 1 % of the best") for t in texts)
    assert "4 failed starts (no SSR)" in texts  # 2 non-finite costs + n_failed=2
    crosses = [c for c in ax.collections if "failed" in (c.get_label() or "")]
    assert len(crosses) == 1 and crosses[0].get_offsets().shape[0] == 4
    assert_no_overlap(fig)
    assert_inside(fig)


def test_waterfall_all_failed_and_no_floor():
    fig, ax = plots.plot_waterfall([], n_failed=3)
    assert "3 failed starts (no SSR)" in legend_texts(ax)
    fig, ax = plots.plot_waterfall([5.0])
    assert not [ln for ln in ax.get_lines() if "floor" in ln.get_label()]
    assert legend_texts(ax) == ["1 of 1 starts within 1 % of the best (5 rad²)"]
    # the longest legend line a multistart writes still fits the page
    fig, ax = plots.plot_waterfall(
        np.r_[1.23456e-5 * (1 + 1e-4 * np.arange(480)), np.geomspace(1.0, 1e3, 520)],
        n_failed=1000,
        noise_floor_ssr=9.87654e-5,
        near=0.001,
    )
    assert_inside(fig)


def test_quantisation_floor_ssr():
    ex = SimpleNamespace(n=1000)
    prob = SimpleNamespace(
        experiments=[ex, ex],
        channels=("theta_u", "theta_l"),
        weights={"theta_u": 1.0, "theta_l": 2.0},
    )
    q_u, q_l = quantisation_floor("theta_u"), quantisation_floor("theta_l")
    want = 2000 * q_u**2 + 2000 * (2 * q_l) ** 2
    assert plots.quantisation_floor_ssr(prob) == pytest.approx(want)


# ----------------------------------------------------------------------- stick shading
def _stick_mode(n=3000):
    mode = np.ones(n, dtype=np.int8)
    mode[200:700] = 0
    mode[1500:1600] = 0
    return mode


def test_fit_legends_list_stick_shading_on_each_shaded_axis():
    t = np.arange(3000) * 1e-2
    meas = {"theta_l": np.sin(t), "alpha": np.cos(t)}
    sim = {"theta_l": np.sin(t) + 1e-3, "alpha": np.cos(t) - 1e-3}
    fig, axes = plots.plot_fit(
        t,
        meas,
        sim,
        mode=_stick_mode(),
        title="brake: est data x.csv",
        metrics={"theta_l": "R² 0.9990", "alpha": "R² 0.9980"},
    )
    assert len(axes) == 4
    for ax in axes:
        assert any(isinstance(p, matplotlib.patches.Polygon) or p.get_label() for p in ax.patches)
        assert "lower disc sticks" in legend_texts(ax)
    assert legend_texts(axes[0])[:2] == ["measured", "simulated"]
    assert axes[0].get_ylabel() == r"$\theta_l$ [rad]"
    assert axes[1].get_ylabel() == r"$\theta_l$ error [rad]"
    assert axes[3].get_ylabel() == r"$\alpha$ error [rad]"
    assert axes[-1].get_xlabel() == "t [s]"
    assert "R² 0.9990" in axes[0].get_title(loc="left")
    # legends sit right of the data area, never on it
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    for ax in axes:
        assert ax.get_legend().get_window_extent(r).x0 >= ax.get_window_extent(r).x1
    assert_no_overlap(fig)
    assert_inside(fig)


def test_long_fit_lines_keep_every_pixel_columns_extremes():
    """600 s at 1 kHz of noisy error: in every pixel column of the drawn figure, the
    highest and lowest sample are drawn (within a pixel), and the line ends where the
    record does."""
    rng = np.random.default_rng(4)
    t = np.arange(600_001) * 1e-3
    meas = {"theta_u": np.sin(t / 30) + 1e-4 * rng.standard_normal(t.size)}
    sim = {"theta_u": np.sin(t / 30)}
    fig, axes = plots.plot_fit(t, meas, sim, title="long")
    fig.canvas.draw()
    err_line = axes[1].get_lines()[0]
    xd, yd = err_line.get_xdata(), err_line.get_ydata()
    assert xd.size <= plots.MAX_LINE_POINTS
    assert xd[0] == t[0] and xd[-1] == t[-1]
    y = meas["theta_u"] - sim["theta_u"]
    px = axes[1].transData.transform(np.c_[t, np.zeros_like(t)])[:, 0]
    col = np.floor(px - px.min()).astype(int)
    dcol = np.floor(axes[1].transData.transform(np.c_[xd, 0 * xd])[:, 0] - px.min()).astype(int)
    ncol = col.max() + 1
    smax, smin = np.full(ncol, -np.inf), np.full(ncol, np.inf)
    np.maximum.at(smax, col, y)
    np.minimum.at(smin, col, y)
    dmax, dmin = np.full(ncol + 2, -np.inf), np.full(ncol + 2, np.inf)
    np.maximum.at(dmax, dcol + 1, yd)
    np.minimum.at(dmin, dcol + 1, yd)
    # the drawn extremes within one pixel column either side
    near_max = np.maximum(np.maximum(dmax[:-2], dmax[1:-1]), dmax[2:])
    near_min = np.minimum(np.minimum(dmin[:-2], dmin[1:-1]), dmin[2:])
    assert ncol > 500
    assert np.all(near_max >= smax) and np.all(near_min <= smin)


def test_no_stick_no_shading_entry():
    t = np.linspace(0, 1, 50)
    fig, axes = plots.plot_fit(t, {"theta_u": t}, {"theta_u": t}, mode=np.ones(50))
    assert "lower disc sticks" not in legend_texts(axes[0])


def test_glitches_are_marked_in_their_channels_panels_and_the_torsions():
    """A fit's figure used to show the repaired curve with no sign that samples were left
    out: each glitch is a line at its time, labelled left out or kept."""
    from rotorbayes.io.glitches import Glitch

    t = np.linspace(0, 2, 200)
    g = [
        Glitch("theta_l", 50, float(t[50]), 87.0, 1.0, 0.9),
        Glitch("theta_l", 120, float(t[120]), -40.0, 1.0, 0.9),
        Glitch("theta_u", 80, float(t[80]), 300.0, 1.0, 0.9, left_out=False),
    ]
    fig, axes = plots.plot_fit(
        t, {"theta_u": t, "alpha": t}, {"theta_u": t, "alpha": t}, glitches=g
    )
    upper, torsion = axes[0], axes[2]
    assert "1 glitch kept" in legend_texts(upper)
    assert not any("left out" in x for x in legend_texts(upper))  # theta_l's: not here
    assert {"2 glitches left out", "1 glitch kept"} <= set(legend_texts(torsion))
    xs = sorted(
        float(ln.get_xdata()[0])
        for ln in torsion.get_lines()
        if ln.get_color() == plots.GLITCH_COLOR
    )
    assert xs == pytest.approx([t[50], t[80], t[120]])
    # No glitch: no entry.
    fig, axes = plots.plot_fit(t, {"theta_u": t}, {"theta_u": t})
    assert not any("glitch" in x for x in legend_texts(axes[0]))


@pytest.fixture(scope="module")
def brake_sim():
    import rotorbayes as rb

    _, u = rb.signals.estimation_signal(8.0, seed=1)
    sim = rb.simulate("thesis:4.3:P_ref", u, dt=1e-3, config="brake", alpha0=0.5)
    assert (sim.mode_l == 0).any()
    return sim


def test_simulation_legends_list_stick_shading(brake_sim):
    fig, axes = plots.plot_simulation(brake_sim)
    assert fig._suptitle.get_text() == "simulation, brake configuration"
    for ax in axes[1:]:
        assert "lower disc sticks" in legend_texts(ax)
    assert axes[3].get_ylabel() == r"$\omega$ [rad/s]"
    assert_no_overlap(fig)
    assert_inside(fig)


# ----------------------------------------------------------------------------- friction
def test_friction_title_and_legend_agree():
    p = resolve("thesis:5.2:P0", config="coupled")
    ref = resolve("thesis:4.3:P0", config="brake")
    fig, axes = plots.plot_friction(
        p, reference=ref, title="fitted friction, coupled configuration"
    )
    assert fig._suptitle.get_text() == "fitted friction, coupled configuration"
    for row, disc in enumerate(("upper disc", "lower disc")):
        for ax in axes[row]:
            assert legend_texts(ax) == [f"{disc}, fitted", f"{disc}, reference"]
            assert ax.get_title().startswith(disc)
            assert ax.get_xlabel() == r"angular velocity $\omega$ [rad/s]"
            assert ax.get_ylabel() == "friction torque [N m]"
    fig, axes = plots.plot_friction(p, discs=("u",), label="estimated")
    assert fig._suptitle.get_text() == "estimated friction"
    assert legend_texts(axes[0, 0]) == ["upper disc, estimated"]
    assert_no_overlap(fig)
    assert_inside(fig)


def test_friction_draws_asymmetry_and_stribeck():
    base = resolve("thesis:5.2:P0", config="coupled")
    p = dict(base, dTc_l=0.004, db_l=-0.003, Ts_l=0.03, ws_l=0.05, delta_l=1.0)
    fig, axes = plots.plot_friction(p, discs=("l",), omega_zoom=0.1, shape="rational")
    ax = axes[0, 1]
    neg, pos, stick = ax.get_lines()[:3]
    # slip branches start at the break-away levels -(Ts - dTc) and Ts + dTc
    assert pos.get_ydata()[0] == pytest.approx(0.03 + 0.004, rel=1e-6)
    assert neg.get_ydata()[-1] == pytest.approx(-(0.03 - 0.004), rel=1e-6)
    # rational Stribeck with delta 1 at |omega| = 0.1: Tc + dTc + (b+db) w + (Ts-Tc)/(1+2)
    w = pos.get_xdata()[-1]
    want = 0.0171 + 0.004 + (0.0092 - 0.003) * w + (0.03 - 0.0171) / (1 + w / 0.05)
    assert w == pytest.approx(0.1)
    assert pos.get_ydata()[-1] == pytest.approx(want, rel=1e-9)
    # the set-valued stick segment at omega = 0
    np.testing.assert_allclose(stick.get_xdata(), [0, 0])
    np.testing.assert_allclose(stick.get_ydata(), [-(0.03 - 0.004), 0.03 + 0.004])


def test_friction_accepts_base_parameters_only():
    p = {"Tc_u": 0.4, "b_u": 2.0, "Tc_l": 0.02, "b_l": 0.01}
    fig, axes = plots.plot_friction(p)
    y = axes[1, 1].get_lines()[1].get_ydata()
    assert np.all(np.isfinite(y)) and y[0] == pytest.approx(0.02, rel=1e-6)
    assert not math.isnan(axes[0, 0].get_lines()[0].get_ydata()[0])


# ---------------------------------------------------------------------------- diagnosis
def test_diagnosis_figures_keep_their_samples_and_fit_the_page(brake_sim):
    """The residual with the candidates' corrections (thinned like every long line, the
    marked samples kept) and the missing-torque map: texts and legends inside the figure,
    none over another."""
    from rotorbayes import inference
    from rotorbayes.diagnosis import diagnose
    from rotorbayes.diagnosis.figures import plot_candidates, plot_torque_map
    from rotorbayes.model.parameters import resolve

    p = resolve("thesis:4.3:P_ref", config="brake")
    ex = brake_sim.to_experiment("b")
    prob = inference.Problem("brake", [ex], base=p)
    x = prob.x_from(p)
    d = diagnose(prob, x)
    fig, axes = plot_candidates(prob, x, d)
    shown = [s for s in d.ranking if s.correction is not None and not s.equivalent_to_free][:3]
    assert shown
    every = max(1, ex.n // 10)
    for k, ax in enumerate(axes[:, 0]):
        lines = ax.get_lines()
        assert lines[0].get_xdata().size <= plots.MAX_LINE_POINTS  # the residual
        seg = slice(k * ex.n, (k + 1) * ex.n)
        for i, (s, line) in enumerate(zip(shown, lines[1:], strict=True)):
            marks = np.asarray(line.get_markevery())
            want = np.arange(i * every // 3, ex.n, every)
            np.testing.assert_array_equal(line.get_xdata()[marks], ex.t[want])
            np.testing.assert_array_equal(line.get_ydata()[marks], -s.correction[seg][want])
            y = -s.correction[seg]
            assert line.get_ydata().max() == y.max() and line.get_ydata().min() == y.min()
    assert_no_overlap(fig)
    assert_inside(fig)
    fig, _ = plot_torque_map(d)
    assert_no_overlap(fig)
    assert_inside(fig)


def test_the_chain_figures_legend_never_covers_a_bar():
    """chain.png's legend sat inside the axes, over the tallest bars of a long chain."""
    from rotorbayes.diagnosis.figures import plot_chain

    fits = [
        {
            "label": f"fit{k}",
            "estimation": {"rms_over_floor": {"theta_u": r, "theta_l": 0.9 * r}},
            "validation": {"rms_over_floor": {"theta_u": 1.2 * r, "theta_l": r}},
        }
        for k, r in enumerate([3000.0, 700.0, 40.0, 1.0])
    ]
    fig, ax = plot_chain({"fits": fits})
    fig.canvas.draw()
    leg = ax.get_legend().get_window_extent()
    assert leg.x0 >= ax.get_window_extent().x1
    assert "encoder floor" in legend_texts(ax)


def test_the_torque_map_draws_one_angle_panel_and_then_other_variables():
    """Three harmonics of the angle were three panels of one picture (each is drawn
    against the angle within a revolution), in place of the direction and the speed."""
    from types import SimpleNamespace

    from rotorbayes.diagnosis.figures import plot_torque_map
    from rotorbayes.diagnosis.torque import TorqueMap

    rng = np.random.default_rng(1)
    n = 400
    ang = rng.uniform(0, 2 * np.pi, n)
    feats = {
        "angle_1": ang,
        "angle_2": ang,
        "angle_3": ang,
        "direction": np.sign(rng.standard_normal(n)),
        "velocity": rng.uniform(-3, 3, n),
    }
    ranking = [("angle_1", 0.67), ("angle_2", 0.66), ("angle_3", 0.64), ("direction", 0.62)]
    ranking.append(("velocity", 0.57))
    m = TorqueMap("l", np.zeros(n), rng.standard_normal(n), feats, ranking, 1.0, 0.1)
    fig, axes = plot_torque_map(SimpleNamespace(maps=[m]))
    titles = [ax.get_title() for ax in axes[0]]
    assert sum("angle" in t for t in titles) == 1, titles
    assert "direction" in titles[1] and "velocity" in titles[2], titles
