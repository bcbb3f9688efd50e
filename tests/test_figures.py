"""Paper figures on synthetic inputs: the t-SNE legends (figure 10), the variant-set bars
(figure 8) and the strobe picture (figure 11)."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from gcnt.analysis import bars, embed, strobe  # noqa: E402
from gcnt.analysis.names import display_name  # noqa: E402
from gcnt.analysis.runs import AnalysisError, method_key  # noqa: E402

# ----------------------------------------------------------------------------- figure 10


def _embedding(title: str, robots: int = 30, seed: int = 0) -> embed.Embedding:
    """Limbs of ``robots`` robots from three families, four limb types each."""
    rng = np.random.default_rng(seed)
    families = ["cheetah", "walker", "hopper"]
    types = ["torso", "thigh", "shin", "foot"]
    names, fams, kinds = [], [], []
    for r in range(robots):
        for t in types:
            names.append(f"robot_{r}")
            fams.append(families[r % 3])
            kinds.append(t)
    return embed.Embedding(title, rng.normal(size=(len(names), 8)), kinds, names, fams)


def _legend(fig, title: str) -> list[str]:
    (leg,) = [lg for lg in fig.legends if lg.get_title().get_text().startswith(title)]
    return [t.get_text() for t in leg.get_texts()]


def test_embedding_legends_are_families_and_limb_types() -> None:
    """One legend of families (markers) and one of limb types (colours), however many robots."""
    es = [_embedding("a"), _embedding("b", seed=1)]
    coords = [np.random.default_rng(i).normal(size=(len(e.vectors), 2)) for i, e in enumerate(es)]
    fig = embed.embedding_figure(es, coords)
    try:
        assert len(fig.legends) == 2
        assert _legend(fig, "robot family") == ["walker", "cheetah", "hopper"]
        assert _legend(fig, "limb type") == ["torso", "thigh", "shin", "foot"]
        (fam,) = [lg for lg in fig.legends if lg.get_title().get_text().startswith("robot")]
        markers = [h.get_marker() for h in fam.legend_handles]
        assert len(set(markers)) == 3
        for ax in fig.axes:  # a scatter per family, drawn with the family's marker
            assert len(ax.collections) == 3
            assert sum(len(c.get_offsets()) for c in ax.collections) == 120
    finally:
        plt.close(fig)
    with pytest.raises(ValueError, match="coordinates of shape"):
        embed.embedding_figure(es[:1], [np.zeros((5, 2))])


def test_limb_type_colour_does_not_depend_on_the_other_types() -> None:
    a = embed._type_colours(["foot", "thigh"])
    b = embed._type_colours(["torso", "foot", "upper_arm"])
    assert a["foot"] == b["foot"]
    assert len(set(embed._type_colours(["torso", "thigh", "shin", "foot"]).values())) == 4


# ----------------------------------------------------------------------------- figure 8


INTERVAL = "90% CI: stratified percentile bootstrap over seeds"


def _summary() -> dict:
    """The shape of ``variants.variant_summary``'s output; intervals reach beyond the points
    (one below zero) and one is missing (nan: one seed)."""
    rng = np.random.default_rng(0)
    out: dict = {}
    for name, level in (("variants-kinematics", 800.0), ("variants-dynamics", 2400.0)):
        entry = {}
        for m, shift in (("gcnt", 300.0), ("modumorph", 0.0), ("metamorph", -900.0)):
            item = {"robots": 20, "seeds": 3, "scores": {}, "interval": INTERVAL,
                    "protocol": "deterministic, 10 episodes per robot"}  # fmt: skip
            for kind, k in (("mean", 0.0), ("iqm", 50.0)):
                p = level + shift + k + float(rng.normal(0.0, 50.0))
                item[kind] = {"point": p, "low": p - 400.0, "high": p + 600.0}
            entry[m] = item
        out[name] = entry
    for kind in ("mean", "iqm"):
        out["variants-dynamics"]["metamorph"][kind].update(low=math.nan, high=math.nan)
    return out


@pytest.mark.parametrize("stats", [("mean",), ("mean", "iqm")])
def test_bars_share_the_y_range_and_hold_every_interval(stats) -> None:
    summary = _summary()
    fig = bars.bar_figure(summary, stats)
    try:
        axes = fig.axes
        assert len(axes) == 2
        bottom, top = axes[0].get_ylim()
        assert all(ax.get_ylim() == (bottom, top) for ax in axes)
        ends = [
            v
            for entry in summary.values()
            for item in entry.values()
            for k in stats
            for v in (item[k]["low"], item[k]["high"], item[k]["point"])
            if math.isfinite(v)
        ]
        assert bottom < min(ends) < 0.0 and max(ends) < top  # nothing clipped, with a margin
        for ax, name in zip(axes, summary, strict=True):
            order = sorted(["gcnt", "modumorph", "metamorph"], key=method_key)
            shown = [display_name(m) for m in order]  # methods by their display names
            assert [t.get_text() for t in ax.get_xticklabels()] == shown
            assert ax.get_xlim() == axes[0].get_xlim()
            assert ax.get_title().startswith(name)
            heights = sorted(p.get_height() for p in ax.patches)
            points = sorted(item[k]["point"] for item in summary[name].values() for k in stats)
            assert heights == pytest.approx(points, rel=1e-12)
        # an error bar per finite interval: the nan one (metamorph, dynamics) has none
        caps = [len([c for c in ax.containers if type(c).__name__ == "ErrorbarContainer"])
                for ax in axes]  # fmt: skip
        assert caps == [3 * len(stats), 2 * len(stats)]
        assert axes[0].get_ylabel().startswith("zero-shot return")
        assert fig._suptitle is None  # the caption goes beside the figure, not into its title
        caption = bars.caption(summary)
        assert f"Error bars: {INTERVAL}." in caption
        assert "Evaluation: deterministic, 10 episodes per robot." in caption
        other = bars.caption(summary, interval="95% CI of something else")
        assert "Error bars: 95% CI of something else." in other
    finally:
        plt.close(fig)


def test_bars_refuse_an_empty_summary_and_write_a_png(tmp_path: Path) -> None:
    with pytest.raises(AnalysisError, match="no variant set"):
        bars.bar_figure({})
    with pytest.raises(AnalysisError, match="none of the statistics"):
        bars.bar_figure(_summary(), ("median",))
    png = bars.plot_bars(_summary(), tmp_path / "bars.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_bar_limits_include_zero_and_a_margin() -> None:
    s = {"a": {"m": {"mean": {"point": 10.0, "low": 5.0, "high": 20.0}}}}
    assert bars.bar_limits(s, ("mean",)) == (0.0, 20.0 + bars.MARGIN * 20.0)
    s["a"]["m"]["mean"] = {"point": -10.0, "low": -30.0, "high": math.nan}
    assert bars.bar_limits(s, ("mean",)) == (-30.0 - bars.MARGIN * 30.0, 0.0)


# ----------------------------------------------------------------------------- figure 11


def test_strobe_frames_by_time_when_moving_by_position_when_not() -> None:
    moving = np.linspace(0.0, 5.0, 200)
    assert strobe.strobe_frames(moving, 8, 0.3).tolist() == (
        np.linspace(0, 199, 8).round().astype(int).tolist()
    )
    rng = np.random.default_rng(0)
    slow = np.cumsum(rng.normal(0.004, 0.01, size=300))  # ~1 m in 300 steps, jittering
    idx = strobe.strobe_frames(slow, 8, 0.3)
    assert idx[-1] == 299 and len(idx) <= 8 and np.all(np.diff(idx) > 0)
    assert np.all(np.abs(np.diff(slow[idx])) >= 0.3)
    assert strobe.strobe_frames(np.zeros(50), 8, 0.3).tolist() == [49]  # one pose, no blob
    with pytest.raises(ValueError, match="non-empty"):
        strobe.strobe_frames(np.zeros(0))


def test_strobe_figure_has_a_row_per_run() -> None:
    images = [np.full((40, 160, 3), 200 + 10 * i, dtype=np.uint8) for i in range(4)]
    labels = ["gcnt", "amorpheus", "swat", "smp"]
    fig = strobe.strobe_figure(images, labels, title="t")
    try:
        assert [ax.get_ylabel() for ax in fig.axes] == labels
        assert all(len(ax.images) == 1 for ax in fig.axes)
    finally:
        plt.close(fig)
    with pytest.raises(ValueError, match="row labels"):
        strobe.strobe_figure(images, labels[:2])


def test_strobe_image_light_floor_with_marks() -> None:
    """A humanoid walking 3 m: light picture, dark distance lines, robot drawn at each pose."""
    import mujoco

    from gcnt.morphology import resolve_robots

    robot = resolve_robots(["humanoid_2d_9_full"])[0]
    model = mujoco.MjModel.from_xml_path(str(robot.source))
    data = mujoco.MjData(model)
    poses = np.zeros((60, model.nq))
    poses[:, 0] = np.linspace(0.0, 3.0, 60)  # the torso's x slide
    xs = strobe.root_x(model, data, poses)
    assert xs[-1] - xs[0] == pytest.approx(3.0)
    idx = strobe.strobe_frames(xs, 4)
    image = strobe.strobe_image(model, data, poses, idx, width=480)
    h, w, _ = image.shape
    assert w == 480 and w // 6 - 2 <= h <= w // 3
    grey = image.astype(np.float64).mean(2)
    assert np.median(grey) > 200  # light floor and background
    assert (grey < 110).sum() > 100  # distance lines
    robot_px = (image[..., 0].astype(int) - image[..., 2].astype(int)) > 60  # orange-brown
    cols = np.flatnonzero(robot_px.any(0))
    assert cols.max() - cols.min() > w / 3  # the poses spread along the path


def test_strobe_command_refuses_bad_numbers(tmp_path: Path) -> None:
    from gcnt.cli import main

    assert main(["strobe", str(tmp_path), "--frames", "0"]) == 2
    with pytest.raises(AnalysisError, match="no run"):
        strobe.strobe_runs([], tmp_path)
