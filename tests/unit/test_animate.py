"""Animations (vcirun.run.animate): real frames rendered headless (Agg, no pyplot). The frame count follows fps,
speed and max_frames; frames differ where the state differs and not where it does not; the first frame
shows the geometry where it is (pixels at the drawn points against their data coordinates); walkers
advance at each heel strike; GIF files hold every frame; the `draw:` section and the fallback."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.run.plotting import COLORS

ROOT = Path(__file__).resolve().parents[2]


def _rgb(hexcolor):
    return np.array([int(hexcolor[i:i + 2], 16) for i in (1, 3, 5)])


def _near(img, rc, color, radius=2, tol=40):
    """Some pixel within `radius` of (row, col) has `color` (antialiasing blends the edges)."""
    r, c = rc
    patch = img[max(0, r - radius):r + radius + 1, max(0, c - radius):c + radius + 1].reshape(-1, 3).astype(int)
    return bool(np.any(np.max(np.abs(patch - color), axis=1) <= tol))


def _crop(anim, img, ax):
    """The part of a frame inside axes `ax`."""
    x0, y0, x1, y1 = ax.get_window_extent().extents
    h = img.shape[0]
    return img[int(h - y1) + 1:int(h - y0) - 1, int(x0) + 1:int(x1) - 1]


@pytest.fixture(scope="module")
def pendulum():
    """The double pendulum from rest with both links horizontal (away from the wall), 1 s."""
    return vcirun.simulate("double_pendulum", "CVA", h=1e-3, T=1.0, q0=[-np.pi / 2, -np.pi / 2], p0=[0.0, 0.0])


def test_frame_count_follows_fps_speed_and_the_cap(pendulum):
    a = pendulum.animate()
    assert a.n_frames == 31 and a.speed == 1.0 and np.allclose(np.diff(a.times), 1 / 30)
    b = pendulum.animate(fps=10, speed=0.5)
    assert b.n_frames == 21 and b.times[-1] == pytest.approx(1.0)
    c = pendulum.animate(max_frames=8)
    assert c.n_frames == 8 and c.speed == pytest.approx(30 / 7) and c.times[-1] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="fps"):
        pendulum.animate(fps=0)


def test_first_frame_shows_the_geometry_where_it_is(pendulum):
    """Both links horizontal at t = 0: the tips' dots at (-1, 0) and (-2, 0), the links' colour midway
    along them, the pivot's triangle at the origin, the wall line at x = 1.2, nothing at (0, -1.5)."""
    a = pendulum.animate()
    img = a.frame(0)
    assert img.shape == (400, 800, 3) and img.dtype == np.uint8
    ax = a.scene_ax
    dot, link = _rgb(COLORS[1]), _rgb(COLORS[0])
    for x in (-1.0, -2.0):
        assert _near(img, a.to_pixels(ax, x, 0.0), dot)
    for x in (-0.5, -1.5):
        assert _near(img, a.to_pixels(ax, x, 0.0), link)
    assert _near(img, a.to_pixels(ax, 0.0, 0.0), np.array([51, 51, 51]), radius=4)
    assert _near(img, a.to_pixels(ax, 1.2, -0.5), np.array([64, 64, 64]), radius=1)
    r, c = a.to_pixels(ax, -1.0, -1.2)
    assert np.all(img[r - 3:r + 4, c - 3:c + 4] == 255)
    # the pixel positions move with the state: at t = 0.5 the tips have fallen, the first tip on its circle
    q = pendulum(a.times[15])
    img15 = a.frame(15)
    assert _near(img15, a.to_pixels(ax, np.sin(q[0]), -np.cos(q[0])), dot)
    assert not _near(img15, a.to_pixels(ax, -2.0, 0.0), dot)


def test_frames_differ_where_the_state_differs():
    """The rocking block: the scene's pixels change while it moves and not once it rests (no impact
    star, the same state); the energy cursor and the time bar move in every frame."""
    tr = vcirun.simulate("rocking_block", "CVA", h=1e-3, T=3.0)
    a = tr.animate(fps=10)
    assert a.n_frames == 31
    moving = [_crop(a, a.frame(i), a.scene_ax) for i in (0, 1, 2)]
    assert not np.array_equal(moving[0], moving[1]) and not np.array_equal(moving[1], moving[2])
    assert np.ptp(tr(a.times[[25, 30]]), axis=0).max() < 1e-12        # at rest from t ~ 1.05
    late = [a.frame(i) for i in (25, 30)]
    assert np.array_equal(_crop(a, late[0], a.scene_ax), _crop(a, late[1], a.scene_ax))
    assert not np.array_equal(_crop(a, late[0], a.bar_ax), _crop(a, late[1], a.bar_ax))
    assert not np.array_equal(_crop(a, late[0], a.energy_ax), _crop(a, late[1], a.energy_ax))
    # an impact star where the first impact happened (the block's corner on the floor)
    k = int(np.searchsorted(a.times, tr.impacts[0]))
    img = a.frame(k)
    i = tr.impact_contact[0]
    corner = a.scene.P[k, a.scene.contact_idx[i]]
    assert _near(img, a.to_pixels(a.scene_ax, *corner), np.array([213, 94, 0]), radius=3)


def test_walker_advances_at_each_heel_strike():
    """The compass gait: at each impact the drawing moves by the swing foot's position (the new stance
    foot), so the stance foot steps down the slope by one step length per stride; it stays in view."""
    tr = vcirun.simulate("compass_gait", "CVA", h=1e-3, T=3.0)
    a = tr.animate(fps=20)
    sc = a.scene
    stance, swing = sc.nd.index["stance"], sc.nd.index["swing"]
    k = np.searchsorted(a.times, tr.impacts, side="right")   # first frame after each impact
    assert len(tr.impacts) >= 3
    for j in range(len(tr.impacts) - 1):
        before = sc.P[k[j] - 1, swing]
        # after heel strike j the stance foot is where the swing foot landed (to its motion in one frame)
        assert np.allclose(sc.P[k[j], stance], before, atol=0.05)
        step = sc.P[k[j + 1], stance] - sc.P[k[j], stance]
        assert 0.4 < np.hypot(*step) < 0.7 and step[0] > 0 and step[1] < 0   # downhill, to the right
    a.frame(k[-1])
    xlo, xhi = a.scene_ax.get_xlim()
    assert xlo < sc.P[k[-1], stance][0] < xhi


def test_gif_holds_every_frame_and_mp4_needs_ffmpeg(tmp_path, pendulum):
    from PIL import Image

    a = pendulum.animate(fps=10)
    path = a.save(tmp_path / "p.gif")
    with Image.open(path) as im:
        assert im.n_frames == a.n_frames == 11 and im.size == (800, 400)
    with pytest.raises(ValueError, match="unknown animation format"):
        a.save(tmp_path / "p.avi")
    if shutil.which("ffmpeg") is None:
        with pytest.raises(ValueError, match="ffmpeg"):
            a.save(tmp_path / "p.mp4")
    else:
        assert a.save(tmp_path / "p.mp4").stat().st_size > 1000
    assert "<script" in a.to_html()[:20000] or "<div" in a.to_html()[:2000]


def test_draw_section_and_its_errors(tmp_path):
    """docs/examples/spring_pendulum.yaml's draw: section is used; a bad one names its field."""
    sp_path = ROOT / "docs" / "examples" / "spring_pendulum.yaml"
    tr = vcirun.simulate(str(sp_path), "CVA", h=1e-3, T=0.5, q0=[1.2, -1.0], p0=[0.0, 0.0])
    a = tr.animate(fps=10)
    assert type(a.scene).__name__ == "_BodyScene" and a.scene.spring_idx
    img = a.frame(0)
    assert _near(img, a.to_pixels(a.scene_ax, 1.2 * np.sin(-1.0), -1.2 * np.cos(-1.0)), _rgb(COLORS[1]))
    from vcirun.mechanics.loader import load_system_yaml

    base = {"coordinates": ["x"], "mass_matrix": [["1"]], "potential": "x**2", "constraint": "x + 1"}
    for draw, field in (({"points": {"a": [0, "x"]}, "segments": [["a", "b"]]}, "draw.segments[0]"),
                        ({"points": {"a": [0, "y"]}}, "draw.points.a"),
                        ({"points": {"a": [0, 0]}, "contacts": ["a", "a"]}, "draw.contacts"),
                        ({"points": {"a": [0, 0]}, "colour": 1}, "draw.colour")):
        with pytest.raises(ValueError, match=field.replace(".", r"\.").replace("[", r"\[")):
            load_system_yaml(base | {"draw": draw})


def test_configuration_space_fallback(tmp_path):
    """A system without a drawing: two coordinates drawn as the point q in their plane, the constraint
    boundary phi = 0 dashed; the point's pixel at q."""
    path = tmp_path / "plain.yaml"
    path.write_text("name: plain2\ncoordinates: [x, y]\nparameters: {g: 9.81}\nmass_matrix: [['1', '0'], ['0', '1']]\n"
                    "potential: 'g*y'\nconstraint: 'y + 0.2*x'\nq0: [0.3, 1.0]\nqdot0: [0.5, 0.0]\n")
    tr = vcirun.simulate(str(path), "CVA", h=1e-3, T=1.0)
    a = tr.animate(fps=10)
    assert type(a.scene).__name__ == "_ConfigScene" and len(tr.impacts) >= 1
    img = a.frame(4)
    q = tr(a.times[4])
    assert _near(img, a.to_pixels(a.scene_ax, q[0], q[1]), _rgb(COLORS[1]))
    assert a.scene_ax.collections   # the dashed boundary contour y = -0.2 x


def test_a_run_that_stopped_at_its_start_names_its_status():
    import warnings

    import pytest

    import vcirun

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tr = vcirun.simulate("painleve_rod", "CVA", T=1, h=0.005)
    assert tr.status == "painleve"
    with pytest.raises(ValueError, match="ended at its start with status painleve"):
        tr.animate()


def test_every_built_in_scene_is_drawn_from_its_geometry():
    """`vcirun animate` draws built-in scenes from their geometry; none falls back to configuration space."""
    from vcirun.scenes.registry import get_scene, listed_scenes

    missing = [n for n in listed_scenes() if getattr(get_scene(n), "drawing", None) is None]
    assert not missing, missing
