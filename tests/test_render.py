"""The one scene renderer (stp_env/render.py): the environment's rgb_array frame has the right shape and shows the
scene, and every scene drawing of the package (the env's frame, the evaluation's episode figure and its GIF) goes
through :func:`stp_env.render.draw_scene`: a marker planted in it appears in each of their images."""

from __future__ import annotations

import jax
import matplotlib.image as mpimg
import numpy as np
import pytest
from matplotlib.patches import Rectangle

import stp_env.render as render
from stp_env.env import parallel_env
from stp_env.evaluation.plots import plot_episode
from stp_env.evaluation.render import render_episode

MAGENTA = np.array([255, 0, 255])
STEPS = 30


def _magenta_pixels(rgb) -> int:
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8:                       # PNGs read back as floats in [0, 1]
        rgb = np.round(255 * rgb).astype(int)
    return int(np.sum(np.all(np.abs(rgb[..., :3].astype(int) - MAGENTA) <= 8, axis=-1)))


@pytest.fixture(scope="module")
def episode():
    """A short episode of the default scenario, recorded from the environment: the env (left at its last step),
    the trajectory ``{field: (T, ...)}`` and a final state in which vehicle 0 started avoiding mid-way."""
    e = parallel_env(render_mode="rgb_array", max_cycles=STEPS + 5)
    e.reset(seed=0)
    rng = np.random.default_rng(0)
    rows = []
    for _ in range(STEPS):
        state = jax.device_get(e.env_state)
        rows.append({k: np.asarray(getattr(state, k)) for k in render.SCENE_FIELDS})
        e.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in e.agents})
    traj = {k: np.stack([r[k] for r in rows]) for k in render.SCENE_FIELDS}
    state = jax.device_get(e.env_state)
    avoid_start = np.full(e.params.vehicles.n, np.inf)
    avoid_start[0] = traj["t"][STEPS // 2]
    final = {"avoid_start": avoid_start, "status": np.asarray(state.status),
             "collision_time": np.asarray(state.collision_time), "t_appear": float(traj["t"][2])}
    yield e, traj, final
    e.close()


@pytest.fixture
def planted(monkeypatch):
    """``draw_scene`` that also fills its axes' lower-left quarter with magenta; records the axes it drew on."""
    original, calls = render.draw_scene, []

    def draw_scene(ax, *args, **kwargs):
        out = original(ax, *args, **kwargs)
        ax.add_patch(Rectangle((0.0, 0.0), 0.5, 0.5, transform=ax.transAxes, color="#ff00ff", zorder=10))
        calls.append(ax)
        return out

    monkeypatch.setattr(render, "draw_scene", draw_scene)
    return calls


@pytest.mark.slow
def test_rgb_array_frame_has_the_figure_shape_and_shows_the_scene(episode):
    e, _, _ = episode
    frame = e.render()
    fig = e._fig
    width, height = fig.canvas.get_width_height()
    assert frame.shape == (height, width, 3) and frame.dtype == np.uint8
    assert (height, width) == (480, 480)                # figsize 6 x 6 in at 80 dpi
    colours = np.unique(frame.reshape(-1, 3), axis=0)
    assert len(colours) > 50                            # not blank: drawn lines, text, patches
    assert np.mean(np.all(frame == 255, axis=-1)) < 0.99      # a blank canvas is all white
    if e.scenario.buildings:                           # the buildings' grey (0.55) is drawn
        assert np.sum(np.all(frame == round(0.55 * 255), axis=-1)) > 100
    assert _magenta_pixels(frame) == 0                  # nothing planted without the fixture


def test_the_env_frame_and_the_episode_figures_draw_through_draw_scene(episode, planted, tmp_path):
    e, traj, final = episode
    frame = e.render()
    assert len(planted) == 1 and _magenta_pixels(frame) > 0.1 * frame.shape[0] * frame.shape[1]

    png = plot_episode(traj, final, e.params, e.scenario, str(tmp_path / "episode.png"), title="planted")
    assert len(planted) == 3                            # both panels
    image = mpimg.imread(png)
    assert _magenta_pixels(image) > 0.05 * image.shape[0] * image.shape[1]

    dt = float(e.params.episode.dt)
    files, n_frames = render_episode(traj, final, e.params, e.scenario, str(tmp_path / "episode.gif"),
                                     frame_dt=5 * dt, margin_s=STEPS * dt, progress=False)
    assert n_frames > 1 and len(planted) >= 3 + n_frames   # every frame drawn by draw_scene
    if files[0].endswith(".gif"):
        from PIL import Image

        with Image.open(files[0]) as gif:
            gif.seek(gif.n_frames - 1)
            image = np.asarray(gif.convert("RGB"))
    else:
        image = mpimg.imread(files[-1])
    assert _magenta_pixels(image) > 0.05 * image.shape[0] * image.shape[1]


def test_the_episode_figure_without_the_plant_has_no_marker(episode, tmp_path):
    e, traj, final = episode
    image = mpimg.imread(plot_episode(traj, final, e.params, e.scenario, str(tmp_path / "episode.png")))
    assert _magenta_pixels(image) == 0
