"""The viewer's modes: a problem with a played-back trajectory, live fabric control, and a
benchmark results browser. Each builds on one `Viewer` (a viser server plus the robot)."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fabrax import config
from fabrax.problems.problem import Problem
from fabrax.robot.kinematics import frame_path, frame_pose
from fabrax.viz.robot_view import RobotView, visual_urdf
from fabrax.viz.scene_view import draw_scene

GOAL = (80, 200, 120)
COMMAND = (230, 200, 60)
PATHS = [(40, 110, 230), (220, 60, 60), (60, 170, 80), (150, 80, 200), (240, 150, 30), (30, 170, 190)]


def camera_view(scene, targets: np.ndarray, elevation: float = 0.45, samples: int = 24) -> tuple[tuple, tuple]:
    """(position, look_at) of a camera that sees every target point (arm base, start and goal hand)
    with the most obstacle clearance along its sight lines; among clear views, the one looking
    across the base-to-goal direction (the motion seen side on)."""
    from fabrax.scene import distance

    centre = targets.mean(0)
    radius = max(1.8, 2.5 * float(np.max(np.linalg.norm(targets - centre, axis=1))))
    azimuth = np.linspace(0.0, 2 * np.pi, samples, endpoint=False)
    eyes = centre + radius * np.stack(
        [np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.full(samples, np.sin(elevation))], 1
    )
    t = np.linspace(0.05, 0.95, 24)[None, None, :, None]
    lines = eyes[:, None, None] + t * (targets[None, :, None] - eyes[:, None, None])  # (views, targets, t, 3)
    clearance = np.asarray(distance(scene, jnp.asarray(lines.reshape(-1, 3), jnp.float32))).reshape(samples, -1).min(1)
    across = targets[-1, :2] - targets[0, :2]
    across = np.array([-across[1], across[0]]) / (np.linalg.norm(across) + 1e-9)
    side = np.abs(np.cos(azimuth) * across[0] + np.sin(azimuth) * across[1])
    best = int(np.argmax(np.where(clearance > 0.02, 1.0, 0.0) * 10.0 + side + np.minimum(clearance, 0.0)))
    return tuple(float(v) for v in eyes[best]), tuple(float(v) for v in centre)


def _not_a_handshake(record) -> bool:
    """logging filter: drop websockets' "opening handshake failed" records (with a traceback each),
    which any connection that is not a browser's websocket (a port probe, a health check) causes."""
    return not str(record.getMessage()).startswith("opening handshake failed")


class Viewer:
    """A viser server showing one robot; GUI toggles for its collision spheres."""

    def __init__(self, robot_name: str | dict = "panda", host: str = "127.0.0.1", port: int = 8080, frame: str | None = None):
        import logging

        import viser

        server_log = logging.getLogger("websockets.server")
        if _not_a_handshake not in server_log.filters:
            server_log.addFilter(_not_a_handshake)

        self.robot_cfg = config.load("robot", robot_name) if isinstance(robot_name, str) else robot_name
        self.robot_name = robot_name  # a configs/robot name or a composed robot config
        self.robot = config.load_robot(robot_name)
        self.frame = frame or self.robot.ee_frame
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (1.6, -1.3, 1.1)
        self.server.initial_camera.look_at = (0.35, 0.0, 0.35)
        self.server.scene.add_grid("/grid", width=2.0, height=2.0, cell_size=0.1, position=(0.0, 0.0, -0.001))
        self._urdf = visual_urdf(self.robot_cfg)
        self.arm = RobotView(self.server, self.robot, self.robot_cfg, "/robot", urdf=self._urdf)
        self.arm.update(self.robot_cfg.get("default_q") or np.zeros(self.robot.dof))
        spheres = self.server.gui.add_checkbox("collision spheres", initial_value=False)
        spheres.on_update(lambda _: self.arm.show_spheres(spheres.value))
        self.nodes: list = []
        self.ghosts: list[RobotView] = []
        self._stop = threading.Event()  # ends the playback thread of what `clear` removes

    @property
    def port(self) -> int:
        return self.server.get_port()

    def ghost(self, q, name: str, color=GOAL, opacity: float = 0.35) -> RobotView:
        g = RobotView(self.server, self.robot, self.robot_cfg, name, color=color, opacity=opacity, urdf=self._urdf)
        g.update(q)
        self.ghosts.append(g)
        return g

    def close(self) -> None:
        """Stop playback and live threads, then the server."""
        self._stop.set()
        self.server.stop()

    def clear(self) -> None:
        self._stop.set()
        self._stop = threading.Event()
        for n in self.nodes:
            n.remove()
        for g in self.ghosts:
            g.remove()
        self.nodes, self.ghosts = [], []

    def show_problem(self, problem: Problem) -> None:
        """Scene, start pose and goal: a ghost arm for a joint goal, a frame for a pose goal; the
        camera frames the arm, its start and its goal from the side where no obstacle hides them."""
        self.nodes += draw_scene(self.server, problem.scene, "/scene")
        self.frame_problem(problem)
        self.arm.update(problem.start_q)
        if problem.goal_q is not None:
            self.ghost(problem.goal_q, "/goal")
        if problem.goal_pose is not None:
            pos, quat = problem.goal_pose
            self.nodes.append(self.server.scene.add_frame("/goal_pose", axes_length=0.1, axes_radius=0.005, position=tuple(pos), wxyz=tuple(quat)))

    def frame_problem(self, problem: Problem) -> None:
        """Point the camera (new and connected clients) at the arm, its start and its goal (`camera_view`)."""
        hand = lambda q: np.asarray(frame_pose(self.robot, jnp.asarray(q, jnp.float32), self.frame).translation())  # noqa: E731
        targets = [np.array([0.0, 0.0, 0.3]), hand(problem.start_q)]
        targets.append(hand(problem.goal_q) if problem.goal_q is not None else np.asarray(problem.goal_pose[0], float))
        self.look(problem.scene, np.stack(targets))

    def look(self, scene, targets: np.ndarray) -> None:
        """Point the camera (new and connected clients) at `targets` (base, start hand, goal) from
        the side where no obstacle of `scene` hides them (`camera_view`)."""
        position, look_at = camera_view(scene, np.asarray(targets, float))
        self.server.initial_camera.position, self.server.initial_camera.look_at = position, look_at
        for client in self.server.get_clients().values():
            client.camera.position, client.camera.look_at = position, look_at

    def ee_line(self, q: np.ndarray, name: str, color) -> None:
        pos = np.asarray(frame_path(self.robot, jnp.asarray(q, jnp.float32), self.frame)[0])
        seg = np.stack([pos[:-1], pos[1:]], axis=1)
        self.nodes.append(self.server.scene.add_line_segments(name, points=seg, colors=color, thickness=0.004))

    def show_commands(self, commands: np.ndarray) -> None:
        """GFCS commands: a ghost arm and a sphere at its end-effector for each."""
        for i, c in enumerate(np.atleast_2d(commands)):
            self.ghost(c, f"/commands/{i}", color=COMMAND, opacity=0.25)
            p = np.asarray(frame_pose(self.robot, jnp.asarray(c, jnp.float32), self.frame).translation())
            self.nodes.append(self.server.scene.add_icosphere(f"/commands/ee_{i}", radius=0.02, color=COMMAND, position=tuple(p)))

    def player(self, arms: list[tuple[RobotView, np.ndarray]], dt: float, on_frame=None) -> None:
        """Time slider and play/pause for one or more arms, each with its own path (T_i, dof);
        `on_frame(k)` updates anything else drawn at step k."""
        steps = max(len(q) for _, q in arms)
        slider = self.server.gui.add_slider("time (s)", min=0.0, max=round((steps - 1) * dt, 2), step=dt, initial_value=0.0)
        play = self.server.gui.add_checkbox("play", initial_value=True)
        self.nodes += [slider, play]

        def pose(_=None):
            k = int(round(slider.value / dt))
            for view, q in arms:
                view.update(q[min(k, len(q) - 1)])
            if on_frame is not None:
                on_frame(k)

        slider.on_update(pose)
        pose()

        stop = self._stop

        def loop():
            while not stop.wait(1 / 30):
                if play.value:
                    t = slider.value + 1 / 30
                    slider.value = 0.0 if t > slider.max else round(t, 2)

        threading.Thread(target=loop, daemon=True).start()


def view_demo(viewer: Viewer, fabric_name: str = "panda", dt: float = 0.01, t_max: float = 7.0) -> dict:
    """The built-in shelf problem, solved by the fabric and played back."""
    from fabrax.problems import batch
    from fabrax.problems.generators import demo_problem
    from fabrax.rollout import reach

    fabric, params = config.load_fabric(viewer.robot, fabric_name)
    problem = demo_problem(viewer.robot)
    viewer.show_problem(problem)  # scene, start and goal appear while the fabric compiles
    status = viewer.server.gui.add_markdown("**Solving with the fabric** (the first call compiles it, about a minute on a laptop CPU)...")
    print("[view] solving the demo problem with the fabric (the first call compiles it, about a minute on a laptop CPU)...", flush=True)
    t0 = time.perf_counter()
    tr = reach(fabric, params, batch([problem]), dt=dt, steps=int(round(t_max / dt)))
    q = np.asarray(tr.q[0, : int(tr.length[0])])
    reached = bool(tr.reached[0])
    status.content = (
        f"**{problem.name}**: {'reached' if reached else 'not reached'} in {len(q) * dt:.2f} s of motion (solved in {time.perf_counter() - t0:.0f} s)"
    )
    viewer.ee_line(q, "/path", PATHS[0])
    viewer.player([(viewer.arm, q)], dt)
    return {"problem": problem.name, "reached": reached, "steps": len(q)}


REST_SPEED = 1e-3  # rad/s: below this on every joint, with the goal and obstacles unmoved, the live loop pauses


def live(viewer: Viewer, fabric_name: str = "panda", dt: float = 0.01, problem: Problem | None = None, substeps: int = 2) -> dict:
    """The fabric runs in real time; drag the goal gizmo and the obstacles and the arm reacts.
    Once the arm rests (every joint slower than REST_SPEED) and nothing has moved, the loop stops
    computing until the goal or an obstacle moves (steps still count the simulated time).

    Each drawn frame advances the fabric `substeps` steps of dt (100 steps/s, 50 frames/s by
    default). Returns a dict that the control thread keeps current: steps taken, the achieved
    rate (fabric steps per second) and the arm's configuration q.
    """
    from fabrax.problems.generators import demo_problem
    from fabrax.rollout import integrate
    from fabrax.scene import COMMON_CAPACITY, from_dict, to_dict

    robot = viewer.robot
    fabric, params = config.load_fabric(robot, fabric_name)
    problem = problem or demo_problem(robot)
    data = to_dict(problem.scene)
    goal_q = problem.goal_q if problem.goal_q is not None else problem.start_q
    start = frame_pose(robot, jnp.asarray(goal_q, jnp.float32), viewer.frame)
    gizmo = viewer.server.scene.add_transform_controls(
        "/goal", scale=0.2, position=tuple(np.asarray(start.translation())), wxyz=tuple(np.asarray(start.rotation().wxyz))
    )
    movers = []
    for i, o in enumerate(data["obstacles"]):
        c = viewer.server.scene.add_transform_controls(f"/obstacles/{i}", scale=0.12, disable_rotations=True, position=tuple(o["center"]))
        movers.append(c)
    handles = draw_scene(viewer.server, data, "/obstacles_geom")
    viewer.nodes += [gizmo, *movers, *handles]
    viewer.frame_problem(problem)
    hint = viewer.server.gui.add_markdown(
        "**Drag** the large frame (the hand's goal pose) or the small arrows on each obstacle: the fabric reacts in real time."
    )
    rate = viewer.server.gui.add_markdown("compiling the fabric step (the first call takes about a minute on a laptop CPU) ...")
    viewer.nodes += [hint, rate]

    def frame(p, s, q, qd):  # `substeps` fabric steps per drawn frame, in one scan
        def one(c, _):
            return integrate(fabric, p, s, c[0], c[1], dt)[:2], None

        return jax.lax.scan(one, (q, qd), None, length=substeps)[0]

    advance = jax.jit(frame)
    aim = jax.jit(lambda pos, quat: fabric.with_pose_goal(params, pos, quat))
    state = {"steps": 0, "hz": 0.0, "running": True, "q": np.asarray(problem.start_q)}
    seen = {"goal": None, "obstacles": None}
    inputs = {}

    def refresh() -> bool:
        """New fabric parameters / scene only when the user moved the goal or an obstacle; True then."""
        changed = False
        goal = np.concatenate([gizmo.position, gizmo.wxyz])
        if seen["goal"] is None or not np.array_equal(goal, seen["goal"]):
            inputs["params"] = aim(jnp.asarray(goal[:3], jnp.float32), jnp.asarray(goal[3:], jnp.float32))
            seen["goal"], changed = goal, True
        where = np.asarray([m.position for m in movers]).reshape(-1, 3)
        if seen["obstacles"] is None or not np.array_equal(where, seen["obstacles"]):
            for o, c, h in zip(data["obstacles"], where, handles):
                o["center"] = c.tolist()
                h.position = c
            inputs["scene"] = from_dict(data).pad(**COMMON_CAPACITY)
            seen["obstacles"], changed = where, True
        return changed

    stop = viewer._stop

    def loop():
        q, qd = jnp.asarray(problem.start_q, jnp.float32), jnp.zeros(robot.dof, jnp.float32)
        t_last, n_last = time.perf_counter(), 0
        next_t = time.perf_counter()
        resting = False
        while state["running"] and not stop.is_set():
            moved = refresh()  # always: it also builds the first parameters and scene
            resting = resting and not moved
            if not resting:  # at rest with nothing moved, the fabric stays at its equilibrium: no work
                q, qd = advance(inputs["params"], inputs["scene"], q, qd)
                state["q"] = np.asarray(q)
                viewer.arm.update(state["q"])
                resting = float(jnp.max(jnp.abs(qd))) < REST_SPEED
            state["steps"] += substeps
            now = time.perf_counter()
            if now - t_last >= 1.0:
                state["hz"] = (state["steps"] - n_last) / (now - t_last)
                rate.content = f"fabric: {state['hz']:.0f} steps/s (real time: {1 / dt:.0f})" + (", at rest" if resting else "")
                t_last, n_last = now, state["steps"]
            next_t += substeps * dt
            time.sleep(max(0.0, next_t - time.perf_counter()))

    threading.Thread(target=loop, daemon=True).start()
    return state


def load_results(run_dir: str | Path) -> tuple[dict, list[dict], dict]:
    """meta, rows and paths {method|problem: q} of a `fabrax bench` (or experiments) run directory."""
    run_dir = Path(run_dir)
    f = run_dir / "results.json"
    if not f.exists():
        raise FileNotFoundError(f"{f}: not a benchmark run directory (no results.json)")
    data = json.loads(f.read_text())
    paths = {}
    if (run_dir / "paths.npz").exists():
        with np.load(run_dir / "paths.npz") as z:
            paths = {k: z[k] for k in z.files}
    return data["meta"], data["rows"], paths


def problems_of(meta: dict, robot) -> dict[str, Problem]:
    """The problems a run was made on, rebuilt from its resolved config."""
    from fabrax.bench.ompl import solvable
    from fabrax.problems.load import load_problems

    cfg = dict(meta["config"])
    if "classes" not in cfg:  # experiments/gfcs.py: one class, test split
        cfg.update(classes=[cfg["class_name"]], split="test", limit=cfg.get("test_limit"))
    return {p.name: p for p in load_problems(cfg, robot, solvable=solvable)}


def results_browser(viewer: Viewer, run_dirs: list[str | Path]) -> dict:
    """Step through the problems of one or more runs; every method's motion side by side."""
    rows, paths, problems = [], {}, {}
    for d in run_dirs:
        meta, r, p = load_results(d)
        rows += r
        paths.update(p)
        problems.update(problems_of(meta, viewer.robot))
    names = sorted({r["problem"] for r in rows if r["problem"] in problems})
    if not names:
        raise ValueError("no problems of these runs could be loaded (is FABRAX_DATA set?)")
    methods = sorted({r["method"] for r in rows})
    pick = viewer.server.gui.add_dropdown("problem", options=names, initial_value=names[0])
    table = viewer.server.gui.add_markdown("")
    state = {"problem": None}

    def show(_=None):
        viewer.clear()
        p = problems[pick.value]
        viewer.show_problem(p)
        arms, lines = [], ["| method | success | EE len (m) | time (s) |", "|---|---|---|---|"]
        for i, m in enumerate(methods):
            row = next((r for r in rows if r["problem"] == p.name and r["method"] == m), None)
            if row is None or not row.get("valid_problem", True):
                continue
            lines.append(f"| {m} | {row['success']} | {row['ee_length']:.2f} | {row['duration_s']:.2f} |")
            q = paths.get(f"{m}|{p.name}")
            if q is None:
                continue
            color = PATHS[i % len(PATHS)]
            arms.append((viewer.ghost(q[0], f"/methods/{i}", color=color, opacity=0.6), q))
            viewer.ee_line(q, f"/methods/path_{i}", color)
            if m.startswith("gfcs") and "commands" in row.get("info", {}):
                viewer.show_commands(np.asarray(row["info"]["commands"]))
        table.content = "\n".join(lines)
        viewer.player(arms or [(viewer.arm, np.asarray([p.start_q]))], float(rows[0].get("dt", 0.01)))
        state["problem"] = p.name

    pick.on_update(show)
    show()
    return state


def skill_view(viewer: Viewer, run_dir: str | Path) -> dict:
    """An experiments/skills.py run: the obstacle, the demonstrations' end-effector paths, and the decoded
    geodesics (plain and reshaped by the obstacle metric) played back side by side; a dropdown picks the pair."""
    run_dir = Path(run_dir)
    try:
        result = json.loads((run_dir / "results.json").read_text())
        paths = np.load(run_dir / "paths.npz")
    except (OSError, ValueError) as e:
        raise ValueError(f"{run_dir}: not a skills run (results.json, paths.npz): {e}") from e
    if "obstacle" not in result or "plain" not in paths:
        raise ValueError(f"{run_dir}: not a skills run (no obstacle or decoded paths)")
    o = result["obstacle"]
    scene = {"obstacles": [{"type": "sphere", "center": o["center"], "radius": o["radius"]}]}
    pairs = [str(i) for i in range(len(paths["plain"]))]
    pick = viewer.server.gui.add_dropdown("demonstration", options=pairs, initial_value=pairs[0])
    table = viewer.server.gui.add_markdown("")

    def show(_=None):
        viewer.clear()
        viewer.nodes += draw_scene(viewer.server, scene, "/scene")
        k = int(pick.value)
        arms = []
        for i, (name, color) in enumerate((("plain", PATHS[0]), ("reshaped", PATHS[1]))):
            q = np.asarray(paths[name][k])
            arms.append((viewer.ghost(q[0], f"/skill/{name}", color=color, opacity=0.6), q))
            viewer.ee_line(q, f"/skill/path_{name}", color)
        viewer.arm.update(arms[0][1][0])
        rows = ["| geodesic | EE clearance (cm) | fabric success |", "|---|---|---|"]
        for name in ("plain", "reshaped"):
            rows.append(f"| {name} | {100 * o[name]['ee_clearance_mean_m']:.1f} | {o[name]['fabric_success_rate']:.0%} |")
        table.content = "\n".join(rows)
        viewer.player(arms, 0.05)

    pick.on_update(show)
    show()
    return {"pairs": len(pairs), "demo": result["demo"]}
