"""``perceive`` (AprilTags in rendered or given images, optionally then planned on) and ``rg`` (a scene's
reachability graph)."""

from __future__ import annotations

import argparse
import copy
from typing import Any

from rlgp_exec import progress
from rlgp_exec.cli.common import (
    say,
    scene_arg,
    write_json,
)
from rlgp_exec.cli.flags import (
    SCENE_HELP,
    command,
    json_flag,
)
from rlgp_exec.errors import RlgpError

__all__ = ["add_perceive_commands", "cmd_perceive", "cmd_rg"]


def cmd_perceive(args: argparse.Namespace) -> int:
    if args.image:
        # local: per command, so `rlgp-exec --help` stays fast
        import numpy as np

        from rlgp_exec.perception.camera import CameraIntrinsics
        from rlgp_exec.perception.runner import perceive_image

        if not args.intrinsics:
            raise RlgpError("--image needs --intrinsics W,H,fx,fy,cx,cy (and --tag-size)")
        tags = perceive_image(args.image, CameraIntrinsics.parse(args.intrinsics), args.tag_size, args.detector)
        for t in tags:
            pos = (
                "-" if not t.get("T_camera_tag") else " ".join(f"{v:+.4f}" for v in np.array(t["T_camera_tag"])[:3, 3])
            )
            say(f"tag {t['tag_id']:4d}  {'ok' if t['ok'] else 'rejected':8s}  t_camera_tag [m] {pos}  {t['reason']}")
        if not tags:
            say("no tags found")
        write_json(args.json, {"image": args.image, "tags": tags})
        return 0
    if not args.scene:
        raise RlgpError("give a SCENE file, or --image FILE --intrinsics W,H,fx,fy,cx,cy")
    if args.plan:
        return _perceive_and_plan(args)
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.perception.runner import perceive_scene
    from rlgp_exec.scene import load_scene

    scene = load_scene(scene_arg(args.scene))
    with progress.stage(f"looking around {scene.name} for its tagged objects (rendered head camera)"):
        res = perceive_scene(scene, perturb_m=args.perturb, seed=args.seed, noise_std=args.noise,
                             detector=args.detector)
    say(f"{scene.name}: {res.views} camera views")
    for name in sorted(res.errors_mm):
        err, rot = res.errors_mm[name], res.yaw_errors_deg[name]
        say(f"  {name:20s} position error {err:6.2f} mm  rotation error {rot:5.2f} deg")
    for name in sorted(res.missing):
        say(f"  {name:20s} not seen")
    write_json(
        args.json,
        {
            "scene": scene.name,
            "views": res.views,
            "pos_err_mm": res.errors_mm,
            "rot_err_deg": res.yaw_errors_deg,
            "missing": sorted(res.missing),
            "uncertain": sorted(res.uncertain),
        },
    )
    return 0 if not res.missing else 1


def _perceive_and_plan(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.perceive_plan import perceive_and_plan

    with progress.stage(f"perceiving, then planning with {args.plan}"):
        reports = perceive_and_plan(scene_arg(args.scene), args.plan.split(","), seed=args.seed, perturb_m=args.perturb)
    for r in reports:
        say(r.text())
    write_json(
        args.json,
        {
            "scene": reports[0].scene,
            "perturb_m": args.perturb,
            "seed": args.seed,
            "runs": [
                {
                    "planner": r.planner,
                    "views": r.views,
                    "pos_err_mm": r.errors_mm,
                    "unseen": list(r.unseen),
                    "perceive_s": r.perceive_s,
                    **r.plan.summary(),
                    "true_world_collision_free": None if r.in_truth is None else r.in_truth.collision_free,
                    "true_world_goal_met": None if r.in_truth is None else r.in_truth.goal_met,
                    "ok": r.ok,
                }
                for r in reports
            ],
        },
    )
    return 0 if all(r.ok for r in reports) else 1


def cmd_rg(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    import numpy as np

    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.reach import (
        GraphSnapshot,
        ReachabilityPlanner,
        ReachIK,
        RGParams,
        WorldChecker,
        draw_graph_png,
        load_or_build,
        nominal_q,
    )
    from rlgp_exec.robot import load_robot
    from rlgp_exec.scene import load_scene

    scene = load_scene(scene_arg(args.scene))
    model = load_robot(scene.robot.name)
    with progress.stage(f"building (or loading) {scene.name}'s reachability graph ({args.samples} samples)"):
        graph, stats = load_or_build(scene, params=RGParams(samples=args.samples))
    say(
        f"{scene.name}: {graph.G.number_of_nodes()} nodes, {graph.G.number_of_edges()} edges "
        f"({'loaded from cache' if stats.from_cache else f'built in {stats.build_time_s:.2f} s'})"
    )
    before, before_graph = GraphSnapshot(graph), copy.deepcopy(graph)
    checker = WorldChecker(scene, model.manipulator().group)
    planner = ReachabilityPlanner(graph, ReachIK(model, scene, nominal_q(model, scene)), checker, rng_seed=1)
    rng = np.random.default_rng(1)
    lo, hi = graph.X[graph.alive].min(axis=0), graph.X[graph.alive].max(axis=0)
    shown, ok = None, 0
    with progress.stage(f"{args.queries} random task-space queries"):
        for _ in range(args.queries):
            res = planner.query(rng.uniform(lo, hi), rng.uniform(lo, hi))
            ok += res.ok
            if res.ok and (shown is None or len(res.path) > len(shown)):
                shown = res.path
    path_x = None
    if shown is not None:
        tool = model.manipulator().tool_frame
        path_x = np.array([model.fk(q, tool)[:3, 3] for q in shown])
    say(
        f"{args.queries} random queries: {ok} answered; graph now {graph.G.number_of_nodes()} nodes; {planner.counters}"
    )
    if args.png:
        say(f"wrote {draw_graph_png(graph, scene, args.png, before, path_x, before_graph)}")
    checker.close()
    return 0


def add_perceive_commands(sub: Any) -> None:
    """The ``perceive`` and ``rg`` subcommands."""
    s = command(sub, "perceive", "detect AprilTags in rendered or given images", """
        rlgp-exec perceive sorting_hsr --perturb 0.03
        rlgp-exec perceive sorting_hsr --plan rlgp,gnpp --perturb 0.03
        rlgp-exec perceive --image frame.png --intrinsics 640,480,554,554,320,240 --tag-size 0.04
    """)
    s.add_argument("scene", nargs="?", help="a scene to look around in simulation for its tagged objects: "
                   + SCENE_HELP)
    s.add_argument("--image", help="an image file (PNG/JPEG) from a real camera instead of a scene")
    s.add_argument("--intrinsics", help="with --image: W,H,fx,fy,cx,cy [px]")
    s.add_argument("--tag-size", type=float, default=0.04, help="with --image: black-square edge [m]")
    s.add_argument("--perturb", type=float, default=0.0, help="move objects up to this far [m] from the file")
    s.add_argument("--noise", type=float, default=2.0, help="pixel noise std [grey levels]")
    s.add_argument("--seed", type=int, default=0, help="the perturbation's and the noise's seed")
    s.add_argument("--detector", choices=["opencv", "pupil"], default="opencv", help="the AprilTag detector")
    s.add_argument(
        "--plan",
        help="then plan on the perceived scene with these planners (comma-separated) and replay each plan "
        "in the true world",
    )
    json_flag(s, "the detections (or the perceive-and-plan runs)")
    s.set_defaults(func=cmd_perceive)

    s = command(sub, "rg", "build/draw a scene's reachability graph", """
        rlgp-exec rg sorting_hsr --png rg.png
        rlgp-exec rg my_scene.toml --samples 400 --queries 50
    """)
    s.add_argument("scene", help=SCENE_HELP)
    s.add_argument("--png", help="draw the graph before and after the queries (top and side views)")
    s.add_argument("--samples", type=int, default=200, help="graph nodes to sample")
    s.add_argument("--queries", type=int, default=20, help="random task-space queries to run")
    s.set_defaults(func=cmd_rg)
