"""The browser viewer: scene drawn in a real headless Chromium, live fabric control, results browser."""

import shutil
import socket
import time

import jax.numpy as jnp
import numpy as np
import pytest

from fabrax.robot.kinematics import frame_pose

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def viewer():
    from fabrax.viz.app import Viewer

    v = Viewer("panda", port=_free_port())
    yield v
    v.close()


def _wait(cond, timeout: float = 60.0) -> bool:
    end = time.time() + timeout
    while time.time() < end:
        if cond():
            return True
        time.sleep(0.2)
    return False


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (apt-get install chromium); .ci/run installs it")
def test_demo_is_drawn_in_headless_chromium(viewer, tmp_path):
    playwright = pytest.importorskip("playwright.sync_api", reason="needs playwright (the dev extra)")
    from fabrax.viz.app import view_demo

    info = view_demo(viewer)
    assert info["reached"]
    names = {getattr(n, "name", "") for n in viewer.nodes}
    assert "/scene/cuboid_0" in names and "/path" in names and len(viewer.ghosts) == 1  # shelf, EE path, goal ghost
    args = ["--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
    args += ["--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run"]
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=args)
        page = browser.new_page(viewport={"width": 800, "height": 600})
        page.goto(f"http://127.0.0.1:{viewer.port}")
        assert _wait(lambda: len(viewer.server.get_clients()) >= 1), "the page never connected to the viewer"
        page.wait_for_selector("text=Connected", timeout=60_000)
        time.sleep(4.0)  # meshes arrive and render
        shot = tmp_path / "viewer.png"
        page.screenshot(path=str(shot))
        browser.close()
    import matplotlib.image

    img = (matplotlib.image.imread(shot)[..., :3] * 255).astype(int)
    assert img.std() > 10  # not a blank page
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    shelf = (r > 150) & (g > 70) & (g < 170) & (b < 110) & (r - b > 80)  # the obstacle colour, shaded
    assert shelf.mean() > 0.005, f"obstacle pixels {shelf.mean():.4f}: the scene was not drawn"


def test_live_mode_follows_the_dragged_goal(viewer):
    """Move the goal gizmo as a user's drag would: the fabric brings the hand to it."""
    from fabrax.viz.app import live

    state = live(viewer)
    gizmo = next(n for n in viewer.nodes if getattr(n, "name", "") == "/goal")
    target = np.array([0.45, 0.25, 0.45])
    gizmo.position = target
    assert _wait(lambda: state["steps"] > 400, timeout=120), "the live loop did not run"
    state["running"] = False
    hand = np.asarray(frame_pose(viewer.robot, jnp.asarray(state["q"], jnp.float32), viewer.frame).translation())
    assert np.linalg.norm(hand - target) < 0.05


def test_rl_view_plays_an_episode_of_the_environment(viewer):
    """The switch policy is the pure fabric aimed at the goal: the episode ends in success or runs out."""
    from fabrax.viz.rl_view import rl_view

    cfg = {"substeps": 5, "episode_s": 2.5, "scenes": {"generated": {"flying_cuboids": 1}, "configs_per_scene": 4}}
    info = rl_view(viewer, policy="switch", env_cfg=cfg)
    assert info["scene"] == "flying_cuboids/0000" and 1 <= info["steps"] <= 30
    assert info["fabric_steps"] == 1 + 5 * info["steps"]
    assert not info["collision"]
    names = {getattr(n, "name", "") for n in viewer.nodes}
    assert {"/goal_pose", "/goal_keypoints", "/ee_target", "/exploration", "/bps", "/path"} <= names
    target = next(n for n in viewer.nodes if getattr(n, "name", "") == "/ee_target")
    goal = next(n for n in viewer.nodes if getattr(n, "name", "") == "/goal_pose")
    np.testing.assert_allclose(target.position, goal.position, atol=1e-5)  # switch on: the target is the goal
    shown = [n.content for n in viewer.nodes if hasattr(n, "content") and "policy steps" in str(n.content)]
    assert len(shown) == 1 and f"after {info['steps']} policy steps" in shown[0]  # the outcome is on the page
    assert ("reached the goal" in shown[0]) == info["success"] and "switch" in shown[0]
    assert tuple(viewer.server.initial_camera.position) != (1.6, -1.3, 1.1)  # framed on this episode's scene


def test_results_browser_shows_every_method(viewer, tmp_path, shared_data):
    from fabrax.bench import cli
    from fabrax.viz.app import load_results, results_browser

    assert cli.main(["method=gf", "problems=mbm", "classes=[box]", "limit=1", f"out={tmp_path}", "progress=false"]) == 0
    _, rows, paths = load_results(tmp_path)
    assert set(paths) == {f"gf|{r['problem']}" for r in rows} and paths["gf|box/0051"].shape[1] == 7
    state = results_browser(viewer, [tmp_path])
    assert state["problem"] == "box/0051"
    assert len(viewer.ghosts) == 2  # the goal and the gf motion
    with pytest.raises(FileNotFoundError, match="results.json"):
        load_results(tmp_path / "missing")


def test_skill_view_plays_plain_and_reshaped_geodesics(viewer, tmp_path):
    import json

    from fabrax.viz.app import skill_view

    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785])
    path = q0 + np.linspace(0.0, 0.4, 20)[:, None] * np.array([1.0, 0, 0, 0, 0, 0, 0])
    stats = {"ee_clearance_mean_m": 0.01, "fabric_success_rate": 1.0}
    result = {
        "demo": "jc",
        "obstacle": {"center": [0.45, 0.1, 0.45], "radius": 0.02, "plain": stats, "reshaped": stats},
        "config": {"robot": "panda"},
    }
    (tmp_path / "results.json").write_text(json.dumps(result))
    np.savez(tmp_path / "paths.npz", plain=np.stack([path, path]), reshaped=np.stack([path, path[::-1]]))
    info = skill_view(viewer, tmp_path)
    assert info == {"pairs": 2, "demo": "jc"}
    names = {getattr(n, "name", "") for n in viewer.nodes}
    assert "/scene/sphere_0" in names and "/skill/path_plain" in names and "/skill/path_reshaped" in names
    assert len(viewer.ghosts) == 2
    with pytest.raises(ValueError, match="not a skills run"):
        skill_view(viewer, tmp_path / "missing")


BAD_OPTIONS = [(["demo", "--port", "70000"], "--port must be in 0-65535"), (["demo", "--seconds", "-1"], "--seconds must")]


@pytest.mark.parametrize("args, message", BAD_OPTIONS)
def test_view_cli_rejects_bad_options_before_serving(args, message, capsys):
    from fabrax.viz.cli import main

    with pytest.raises(SystemExit):
        main(args)
    assert message in capsys.readouterr().err


def test_camera_sees_arm_start_and_goal_past_the_obstacles(panda):
    """The initial view of a problem: every sight line to the arm's base, start and goal hands is
    clear of the scene (the built-in shelf stood between the default camera and the arm)."""
    from fabrax.problems.generators import demo_problem
    from fabrax.scene import distance
    from fabrax.viz.app import camera_view

    problem = demo_problem(panda)
    hand = lambda q: np.asarray(frame_pose(panda, jnp.asarray(q, jnp.float32), "panda_hand").translation())  # noqa: E731
    targets = np.stack([np.array([0.0, 0.0, 0.3]), hand(problem.start_q), hand(problem.goal_q)])
    eye, look_at = camera_view(problem.scene, targets)
    t = np.linspace(0.05, 0.95, 50)[:, None, None]
    lines = np.asarray(eye) + t * (targets[None] - np.asarray(eye))
    assert float(np.min(np.asarray(distance(problem.scene, jnp.asarray(lines.reshape(-1, 3), jnp.float32))))) > 0.02
    assert np.allclose(look_at, targets.mean(0))
    old = np.array([1.6, -1.3, 1.1])  # the former fixed camera: its view of the goal crosses the shelf
    lines = old + t * (targets[None] - old)
    assert float(np.min(np.asarray(distance(problem.scene, jnp.asarray(lines.reshape(-1, 3), jnp.float32))))) < 0.0
