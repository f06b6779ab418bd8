"""16 — GNPP's graph-NLPs as a corpus: record every IPOPT run of one plan, re-solve them with other solvers.

    .venv/bin/python tools/16_gnpp_nlp_corpus.py record [SCENE] [--seed K] [--variant gnpp_trn] --out DIR
    .venv/bin/python tools/16_gnpp_nlp_corpus.py compare DIR [--solver ipopt] [--solver sqpmethod:daqp] ...
                                                      [--set ipopt.OPTION=VALUE ...] [--solver lm]
                                                      [--max-factors N] [--arms-only]

``record`` plans SCENE (default tower_pr2) with GNPP, IPOPT answering every NLP (``lm_verdicts=False``),
and keeps what its graph-NLP solver ran (``GraphSolver.observer``): each distinct NLP once, as CasADi's
own serialisation of its oracle (x, p) -> (f, g) (``nlp_K.casadi``); each run's arguments in
``runs.npz`` (numpy, read without pickle) and its metadata in ``runs.json`` (which NLP, factors, IPOPT
with ``SEARCH`` or not, the verdict, iterations, CPU).

``compare`` re-solves every run with each solver and prints, beside the recorded IPOPT runs, how many
verdicts agree, how many differ (both ways), CPU (on the runs IPOPT found feasible / infeasible) and
iterations. A verdict is the planner's: every row and bound within ``FEAS_TOL`` at the solver's point,
and the factors ``presolve`` took out as constants within it too. ``ipopt`` re-solves with the
planner's options (the control: it agrees with the record), ``--set`` changing some of them (e.g.
``--set ipopt.max_soc=0``: does an option keep every verdict, at what CPU?); ``sqpmethod:QP`` is CasADi's SQP with that
QP solver (``daqp``, ``qpoases``, ``osqp``, ...), stopped at the first feasible iterate as IPOPT is;
``lm`` the planner's Levenberg-Marquardt on the rows' violation (``gnpp.lm``, its verdict). ``--max-factors``
and ``--arms-only`` leave the other runs to IPOPT (its recorded verdict and CPU count): a split policy.
Measurements (seed 0 of each scene; CPU of the re-solves, against the recorded IPOPT runs):

    corpus (runs, IPOPT feasible)   solver             agree  feas->inf  CPU ratio
    tower_pr2 (158, 134)            sqpmethod:daqp       157          1       0.28
                                    sqpmethod:qpoases    156          2       0.66  (23 errors)
                                    sqpmethod:osqp       158          0       0.98  (19 errors)
    hanoi_pr2 (351, 267)            sqpmethod:daqp       345          6       0.28
                                    sqpmethod:qpoases    345          6     130
                                    sqpmethod:osqp       348          3       6.2
    obstacles_tower_pr2 (285, 205)  sqpmethod:daqp       281          4       0.17

None called an infeasible run feasible. DAQP's false "infeasible" runs end 10^3-10^9 off their rows and
outside the variable bounds (a failed QP's step taken), as do most of its true ones: an SQP on these
NLPs needs a safeguarded step before its verdicts can replace IPOPT's (the planner kept IPOPT). Without
elastic mode and with its QP failures raised, the SQP raised on 25, 88 and 87 runs: about every run IPOPT
finds infeasible, the expensive kind (60-70 % of IPOPT's CPU here), so IPOPT would still answer those.
IPOPT options tried with ``--set`` (max_resto_iter=20, mu_init=0.01, mu_strategy=adaptive,
nlp_scaling_method=none, limited_memory_initialization=constant, bound_push=0.001, max_soc=0) left the
iterations within -9 %..+29 % and CPU within the re-solves' noise (about +-15 %); max_resto_iter=20 lost a
feasible verdict on Hanoi. linear_solver=spral: the same verdicts at 1.8-2.6x the CPU. A lower iteration
cap, min(K + factors, 400) for the planner's K = 60, over 15 corpora (seeds 0-4 of the three scenes):
K = 30 cut 22-31 % of the iterations but lost a feasible verdict on tower seed 3 and on obstacles seed 3
(3-factor subgraphs that need 37 iterations); K = 10 lost 3 on obstacles seed 0. Only infeasible runs reach
the cap, on tower mostly 4-factor subgraphs, the size of its conflicts (``refute``'s tries, QuickXplain).

The lead: ``--solver lm --max-factors 60 --arms-only`` (LM on the NLPs with arm
variables of up to 60 factors, IPOPT's recorded runs for the rest) agreed with every verdict on seeds 0 and 3
of the three scenes, at 0.47-0.52 of IPOPT's CPU on tower, 0.68-0.76 on obstacles, 0.84-1.01 on Hanoi (its
infeasible runs at 0.4 of IPOPT's on tower). Without ``--arms-only`` it called up to 4 object-only runs
(4-8 variables, ColOO rows) infeasible per corpus; on every NLP (no ``--max-factors``) the large ones made it
slower than IPOPT (tower 2.7 against 1.2 s). Tried in the planner, interleaved with IPOPT
alone, 5 seeds x 2 rounds, and did not land it:
- as it is, and for ``refute`` too: tower seed 2 learnt a third conflict and failed a replay (its points on
  their bounds: the upper arm on the table on the way to the first keyframe);
- with ``refute`` left to IPOPT and inequality rows aimed 1 cm inside their bounds: tower 3.27 / 4.03 s
  against 3.66 / 5.02 s, the same 2 conflicts on every seed;
- but obstacles went to 8.17 / 8.37 s against 6.16 / 7.67 s (seed 3: 2 plans blocked), and Hanoi to 0 of 5
  solved (100 s budget: its "infeasible" answers refuted by IPOPT again and again, every plan blocked).
It is in the planner as an option (``plan_gnpp(lm_verdicts=True)``): the verdict on the true bounds,
the point moved inside them afterwards (``LevenbergMarquardt.polish``), ``refute`` left to IPOPT, fixed-base
arms only. Tower and Hanoi gained, obstacles lost (``solver.LM_MAX_FACTORS`` has the figures).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.planning.gnpp import VARIANTS, plan_gnpp  # noqa: E402
from rlgp_exec.planning.gnpp.lm import LevenbergMarquardt  # noqa: E402
from rlgp_exec.planning.gnpp.solver import SolverRun, ipopt_options, run_feasible  # noqa: E402
from rlgp_exec.scene import load_scene, randomize  # noqa: E402

INPUTS = ("x0", "p", "lbx", "ubx", "lbg", "ubg")
SQP = {
    "hessian_approximation": "limited-memory",
    "elastic_mode": True,
    "tol_pr": 1e-6,
    "tol_du": 1e10,  # feasibility only: the first feasible iterate ends the solve
    "print_header": False,
    "print_iteration": False,
    "print_status": False,
    "print_time": False,
    "error_on_fail": False,
}
QUIET_QP = {  # each QP solver's own switches for its console output
    "qpoases": {"printLevel": "none"},
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
    "osqp": {"osqp": {"verbose": False}},
    "proxqp": {},
    "daqp": {},
}


def record(scene_path: str, seed: int, variant: str, out: Path) -> int:
    scene = load_scene(scene_path)
    if seed:
        scene = randomize(scene, seed)
    out.mkdir(parents=True, exist_ok=True)
    nlp_of: dict[int, int] = {}  # id of the nlpsol Function -> NLP number
    keep: list[ca.Function] = []  # the Functions recorded (their ids stay unique while they live)
    runs: list[dict] = []
    arrays: dict[str, np.ndarray] = {}

    def observe(run: SolverRun) -> None:
        k = nlp_of.get(id(run.solver))
        if k is None:
            k = nlp_of[id(run.solver)] = len(keep)
            keep.append(run.solver)
            run.solver.oracle().save(str(out / f"nlp_{k}.casadi"))
        i = len(runs)
        for name in INPUTS:
            arrays[f"{i}_{name}"] = np.asarray(run.inputs[name], float)
        runs.append(
            {"nlp": k, "factors": run.n_factors, "arms": run.arms, "search": run.search, "feasible": run.feasible,
             "iterations": run.iterations, "cpu_s": run.cpu_s, "fixed_violation": run.fixed_violation}
        )

    res = plan_gnpp(scene, variant, on_nlp=observe, lm_verdicts=False)  # every NLP's IPOPT run
    np.savez(out / "runs.npz", **arrays)
    meta = {"scene": scene.name, "seed": seed, "variant": variant, "status": res.status.value, "runs": runs}
    (out / "runs.json").write_text(json.dumps(meta, indent=1))
    feasible = sum(r["feasible"] for r in runs)
    print(
        f"{scene.name} seed {seed} ({variant}): {res.status.value}; {len(runs)} IPOPT runs of {len(keep)} NLPs "
        f"({feasible} feasible), {sum(r['cpu_s'] for r in runs):.2f} s CPU -> {out}"
    )
    return 0


def _solver(spec: str, oracle: ca.Function, run: dict, changes: dict) -> ca.Function | LevenbergMarquardt:
    plugin, _, qp = spec.partition(":")
    if plugin == "lm":
        return LevenbergMarquardt.of_oracle(oracle, ipopt_options(run["factors"], False)["ipopt.max_iter"])
    if plugin == "ipopt":
        return ca.nlpsol("replay", "ipopt", oracle, {**ipopt_options(run["factors"], run["search"]), **changes})
    if plugin == "sqpmethod":
        opts = {**SQP, "qpsol": qp or "qrqp", "max_iter": ipopt_options(run["factors"], False)["ipopt.max_iter"]}
        opts["qpsol_options"] = {"error_on_fail": False, "print_time": False, **QUIET_QP.get(opts["qpsol"], {})}
        return ca.nlpsol("replay", "sqpmethod", oracle, opts)
    raise SystemExit(f"unknown solver {spec!r}; valid: ipopt, lm, sqpmethod:QP (e.g. sqpmethod:daqp)")


def _changes(settings: list[str]) -> dict:
    """``--set KEY=VALUE`` arguments as IPOPT options (a VALUE that parses as JSON is that value)."""
    out = {}
    for item in settings:
        key, sep, text = item.partition("=")
        if not sep or not key.startswith("ipopt."):
            raise SystemExit(f"--set {item!r}: expected ipopt.OPTION=VALUE, e.g. ipopt.max_soc=0")
        try:
            out[key] = json.loads(text)
        except json.JSONDecodeError:
            out[key] = text
    return out


def compare(corpus: Path, specs: list[str], changes: dict, max_factors: int, arms_only: bool) -> int:
    meta = json.loads((corpus / "runs.json").read_text())
    data = np.load(corpus / "runs.npz", allow_pickle=False)
    runs = meta["runs"]
    oracles = {k: ca.Function.load(str(corpus / f"nlp_{k}.casadi")) for k in sorted({r["nlp"] for r in runs})}
    rec_feas = [bool(r["feasible"]) for r in runs]
    print(f"{meta['scene']} seed {meta['seed']} ({meta['variant']}): {len(runs)} runs of {len(oracles)} NLPs, "
          f"{sum(rec_feas)} feasible by the recorded IPOPT")
    head = f"{'solver':18s} {'agree':>7s} {'feas->inf':>9s} {'inf->feas':>9s} {'errors':>6s} " \
           f"{'CPU [s]':>8s} {'ratio':>6s} {'on feas':>8s} {'on inf':>7s} {'iters':>7s}"
    print(head)
    base = sum(r["cpu_s"] for r in runs)
    on_f = sum(r["cpu_s"] for r in runs if r["feasible"])
    print(f"{'recorded ipopt':18s} {len(runs):7d} {0:9d} {0:9d} {0:6d} {base:8.2f} {1.0:6.2f} {on_f:8.2f} "
          f"{base - on_f:7.2f} {sum(r['iterations'] for r in runs):7d}")
    for spec in specs:
        built: dict[int, ca.Function] = {}
        agree = f2i = i2f = errors = iters = 0
        cpu = [0.0, 0.0]  # on the runs the record calls feasible, infeasible
        for i, r in enumerate(runs):
            if not spec.startswith("ipopt") and (r["factors"] > max_factors or (arms_only and not r.get("arms", True))):
                agree += 1  # left to IPOPT: its recorded answer and CPU
                cpu[0 if r["feasible"] else 1] += r["cpu_s"]
                continue
            a = {name: data[f"{i}_{name}"] for name in INPUTS}
            key = r["nlp"] if not spec.startswith("ipopt") else (r["nlp"], r["search"], r["factors"])
            s = built.get(key)  # type: ignore[arg-type]
            if s is None:
                s = built[key] = _solver(spec, oracles[r["nlp"]], r, changes)  # type: ignore[index]
            c0 = time.process_time()
            try:
                x = np.asarray(s(**a)["x"]).reshape(-1)
                iters += int(s.stats()["iter_count"])
            except RuntimeError:  # e.g. sqpmethod's elastic mode giving up: no point, no verdict
                x, errors = np.full(a["x0"].size, np.nan), errors + 1
            cpu[0 if r["feasible"] else 1] += time.process_time() - c0
            ok = run_feasible(oracles[r["nlp"]], x, a, r["fixed_violation"])
            agree += ok == r["feasible"]
            f2i += r["feasible"] and not ok
            i2f += ok and not r["feasible"]
        total = sum(cpu)
        print(f"{spec:18s} {agree:7d} {f2i:9d} {i2f:9d} {errors:6d} {total:8.2f} {total / max(base, 1e-9):6.2f} "
              f"{cpu[0]:8.2f} {cpu[1]:7.2f} {iters:7d}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="plan a scene with GNPP, keeping every graph-NLP IPOPT ran")
    r.add_argument("scene", nargs="?", default=str(ROOT / "sim" / "scenes" / "tower_pr2.toml"))
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--variant", default="gnpp_trn", choices=list(VARIANTS))
    r.add_argument("--out", type=Path, required=True)
    c = sub.add_parser("compare", help="re-solve a recorded corpus with other solvers")
    c.add_argument("corpus", type=Path)
    c.add_argument("--solver", action="append", default=None, help="ipopt | sqpmethod:QP (repeatable)")
    c.add_argument("--set", action="append", default=[], help="ipopt.OPTION=VALUE for --solver ipopt (repeatable)")
    c.add_argument("--max-factors", type=int, default=10**9, help="other solvers: larger runs left to IPOPT")
    c.add_argument("--arms-only", action="store_true", help="other solvers: runs without arm variables left to IPOPT")
    args = ap.parse_args()
    if args.cmd == "record":
        return record(args.scene, args.seed, args.variant, args.out)
    specs = args.solver or ["ipopt", "sqpmethod:daqp"]
    return compare(args.corpus, specs, _changes(args.set), args.max_factors, args.arms_only)


if __name__ == "__main__":
    sys.exit(main())
