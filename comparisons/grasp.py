"""[GI] Sec. 6.4, Fig. 10: where should a parallel-jaw gripper start to grasp the lock piece?

Question. Brost and Christiansen ran 100,800 physical grasp trials of the lock piece from fingertip-
centre positions (x, y) on a 1 mm grid and found a "sweet spot" near (0, -11) mm, from which
squeezing succeeds almost surely even with +-3 mm of positioning error; [GI] replaced the trials by
simulation (Fig. 10b) and found a plateau of near-certain success of nearly the same size and shape.
This study repeats that: for every cell of the grid, several trials of
``scenes.gear_grasp.simulate_grasp`` with the support and gripper friction coefficients drawn
uniformly from bounded ranges, and the success probability per cell.

What is run. Grid: x = 0..19 mm, y = -19..-1 mm relative to the part's centre, 1 mm apart (380
cells, as dVC's study; the part and the strategy are mirror symmetric about x = 0, so only x >= 0
is simulated and the figure mirrors it). Per cell ``--trials`` trials (default 1; dVC used 25). Trial
k of cell (x, y) draws, from numpy's generator seeded by (--seed, x, y, k): mu_support and
mu_gripper uniformly in --mu-support and --mu-gripper (default both dVC's "medium" range
(0.33, 0.66]), and a start uniformly in the 1 mm patch centred on (x, y) (the histogram counts
trials "with initial conditions in that patch"). So every trial is reproducible on its own, and a
run can stop and resume anywhere.

Success: the test of ``scenes.gear_grasp`` (the part ends held by both jaws, each on the outer flank
of the outer-most tooth on its side, after closing stopped). Failures keep their reason: held
elsewhere, not held, ejected, not stopped, step failure (the stepper raised StepFailure after its
retries: counted as a failure and reported separately), run error (the trial raised anything else).

Sweet spot and plateau (``summarise``): the success probability per cell, mirrored to x in -19..19;
the sweet spot is the cell with the highest mean success over the +-3 mm box around it (the paper's
criterion: high success despite +-3 mm of positioning error; cells outside the grid count as
failures; ties go to the higher mean over the +-2 mm, then the +-1 mm box, then the cell itself,
then to x nearest 0); the plateau is the 4-connected set of cells with success >= PLATEAU_LEVEL that
contains the sweet spot, reported by its x and y extent and its number of cells. With one trial
per cell a cell's value is 0 or 1, so both are coarse: add trials (--trials) to sharpen them.

Executors and scale. Trials are independent: a local process pool on all cores by default
(``--workers``, "spawn" start), ``--workers 0`` in this process, ``--scheduler tcp://host:8786`` on a
Dask cluster (the study uploads scenes/ and comparisons/ to it, see comparisons/executors.py). A
tqdm bar counts finished trials. Every finished trial is appended at once to the results file
(``grasp_trials.csv``) with the study's settings; a rerun with the same settings skips the trials
already there (those that raised run again), so an interrupted study resumes, and the original
100,800 trials (--trials 265 on this grid) are reached by adding workers, not by rewriting.
Throughput: trials per second per core = trials / (sum of their wall times), and trials per second
of the whole run.

Time step. h = 2e-3 s by default (scenes.gear_grasp.H); the x = 0 column rerun at h = 1e-3 s with the
same draws gave the same outcome in all 19 cells, at about twice the cost.

Outputs (in --out, default comparisons/out): grasp_trials.csv (one row per trial, resumable),
grasp_cells.csv (per cell: trials, successes, probability, failures by reason), grasp.png (heat map
and 3D histogram like Fig. 10b, next to the paper's description of Fig. 10a), grasp.md (the
summary printed at the end).

Run: python -m comparisons.grasp [--trials 1] [--mu-support 0.33,0.66] [--mu-gripper 0.33,0.66]
                                 [--workers N] [--scheduler tcp://...] [--out DIR] [--fresh]
"""
from __future__ import annotations

import argparse
import csv
from dataclasses import asdict, dataclass
import math
import os
from pathlib import Path
import time

import numpy as np

from comparisons.executors import completed
from scenes import gear_grasp as gg

DEFAULT_OUT = Path(__file__).resolve().parent / "out"
XS = tuple(range(0, 20))                  # [mm] fingertip-centre x (mirror symmetric: x >= 0)
YS = tuple(range(-19, 0))                 # [mm] fingertip-centre y
MEDIUM = (0.33, 0.66)                     # dVC's "medium" friction range
PLATEAU_LEVEL = 0.9                       # success probability of a plateau cell
SWEET_BOX = 3                             # [mm] half side of the positioning-error box
PAPER_SWEET_SPOT = (0.0, -11.0)           # [mm] Brost and Christiansen, [GI] Sec. 6.4
PAPER_BAND = (-12.0, -9.5)                # [mm] y band of success ~1 (dVC, medium/medium; NOTES.md)
KINDS = ("success", "held elsewhere", "not held", "ejected", "not stopped", "step failure", "run error")
TRIAL_FIELDS = ("settings", "x_mm", "y_mm", "trial", "mu_support", "mu_gripper", "seed", "h", "x0_mm", "y0_mm",
                "success", "kind", "part_x_mm", "part_y_mm", "part_theta", "separation_mm", "time_s", "steps",
                "wall_s", "hold_error_m", "reason")
CELL_FIELDS = ("x_mm", "y_mm", "trials", "successes", "probability") + tuple(
    k.replace(" ", "_") for k in KINDS[1:])
PAPER_FIG10A = (
    "[GI] Fig. 10a (Brost and Christiansen's 100,800 physical trials), as the paper describes it: "
    "half of a symmetric histogram of the fraction of successful trials per 1 mm patch; the sweet spot "
    "is at about (0, -11) mm, where squeezing meets the round rim far enough below the centre for the "
    "part to slide up onto its outer-most teeth; within about +-3 mm of it success is very likely; a "
    "large plateau of near-certain success, dropping off at its edges, with a low area behind it (small "
    "|y|: a nearly diametral grasp). dVC (medium/medium friction): success near 1 for y from about -9.5 "
    "to -12 mm across x, wider near x = 0.")


# ----------------------------------------------------------------------------------------------
# one trial
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrialConfig:
    """One trial (picklable for any executor): cell (x_mm, y_mm) [mm], trial index, the drawn
    frictions and patch seed, the time step h [s] and the study's settings tag."""
    x_mm: int
    y_mm: int
    trial: int
    mu_support: float
    mu_gripper: float
    seed: int
    h: float
    settings: str

    @property
    def key(self) -> tuple:
        return (self.x_mm, self.y_mm, self.trial)


def run_trial(config: TrialConfig) -> dict:
    """simulate_grasp for one config, flattened into a results-file row."""
    out = gg.simulate_grasp(config.x_mm, config.y_mm, config.mu_support, config.mu_gripper,
                            seed=config.seed, h=config.h)
    return {**_config_fields(config), "x0_mm": out.x0_mm, "y0_mm": out.y0_mm, "success": int(out.success),
            "kind": kind_of(out.success, out.reason), "part_x_mm": out.part_mm_rad[0],
            "part_y_mm": out.part_mm_rad[1], "part_theta": out.part_mm_rad[2], "separation_mm": out.separation_mm,
            "time_s": out.time_s, "steps": out.steps, "wall_s": out.wall_s, "hold_error_m": out.hold_error[0],
            "reason": out.reason}


def failed_trial(config: TrialConfig, error: BaseException) -> dict:
    """A trial that raised (not a StepFailure, which simulate_grasp records itself)."""
    return {**_config_fields(config), "x0_mm": math.nan, "y0_mm": math.nan, "success": 0, "kind": "run error",
            "part_x_mm": math.nan, "part_y_mm": math.nan, "part_theta": math.nan, "separation_mm": math.nan,
            "time_s": math.nan, "steps": 0, "wall_s": math.nan, "hold_error_m": math.nan,
            "reason": f"run error: {type(error).__name__}: {error}"}


def _config_fields(config: TrialConfig) -> dict:
    return {k: v for k, v in asdict(config).items()}


def kind_of(success: bool, reason: str) -> str:
    """The outcome class of a trial (KINDS) from scenes.gear_grasp's reason."""
    if success:
        return "success"
    for kind in KINDS[1:]:
        if reason.startswith(kind):
            return kind
    return "run error"


# ----------------------------------------------------------------------------------------------
# the plan
# ----------------------------------------------------------------------------------------------
def settings_tag(mu_support, mu_gripper, seed: int, h: float) -> str:
    """What makes two trials with the same key comparable: friction ranges, seed, h and the scene's
    model constants. Rows with another tag in the results file are kept but not reused."""
    model = (f"R{gg.R:g}/m{gg.M_PART:g}/F{gg.F_GRIP:g}/v{gg.V_CLOSE:g}/mf{gg.M_FINGER:g}/"
             f"vs{gg.V_STOP:g}x{gg.STILL_STEPS}")
    return (f"mu_s={mu_support[0]:g}-{mu_support[1]:g};mu_g={mu_gripper[0]:g}-{mu_gripper[1]:g};"
            f"seed={seed};h={h:g};{model}")


def plan(xs=XS, ys=YS, trials: int = 1, mu_support=MEDIUM, mu_gripper=MEDIUM, seed: int = 0,
         h: float = gg.H) -> list[TrialConfig]:
    """Every trial of the grid, each with its own reproducible draws."""
    if not (isinstance(trials, int) and trials >= 1):
        raise ValueError(f"trials must be an integer >= 1, got {trials!r}")
    for name, (lo, hi) in (("mu_support", mu_support), ("mu_gripper", mu_gripper)):
        if not (0.0 <= lo <= hi and math.isfinite(hi)):
            raise ValueError(f"{name} range must be 0 <= lo <= hi, got ({lo}, {hi})")
    tag = settings_tag(mu_support, mu_gripper, seed, h)
    configs = []
    for x in xs:
        for y in ys:
            for k in range(trials):
                rng = np.random.default_rng([seed, int(x) + 1000, int(y) + 1000, k])
                mu_s = float(rng.uniform(*mu_support))
                mu_g = float(rng.uniform(*mu_gripper))
                configs.append(TrialConfig(int(x), int(y), k, mu_s, mu_g, int(rng.integers(2**31)), h, tag))
    return configs


# ----------------------------------------------------------------------------------------------
# the resumable results file
# ----------------------------------------------------------------------------------------------
def read_trials(path: Path) -> list[dict]:
    """Rows of a results file (numbers parsed), [] if it does not exist."""
    if not Path(path).exists():
        return []
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    for r in rows:
        for k in ("x_mm", "y_mm", "trial", "success", "steps", "seed"):
            r[k] = int(float(r[k]))
        for k in ("mu_support", "mu_gripper", "h", "x0_mm", "y0_mm", "part_x_mm", "part_y_mm", "part_theta",
                  "separation_mm", "time_s", "wall_s", "hold_error_m"):
            r[k] = float(r[k])
    return rows


class TrialWriter:
    """Appends one row per finished trial and flushes it, so a killed study loses nothing."""

    def __init__(self, path: Path):
        self.path = Path(path)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self._handle = open(self.path, "a", newline="")
        self._writer = csv.DictWriter(self._handle, fieldnames=TRIAL_FIELDS)
        if new:
            self._writer.writeheader()
            self._handle.flush()

    def write(self, row: dict) -> None:
        self._writer.writerow({k: row[k] for k in TRIAL_FIELDS})
        self._handle.flush()

    def close(self):
        self._handle.close()


# ----------------------------------------------------------------------------------------------
# running
# ----------------------------------------------------------------------------------------------
@dataclass
class StudyResult:
    rows: list                 # every row of this study's settings in the results file
    ran: int                   # trials run by this call (the others were resumed)
    elapsed_s: float           # wall time of this call's runs
    workers: int
    summary: dict
    paths: dict


def execute(configs, path: Path, scheduler=None, max_workers=None, progress=True) -> tuple[int, float]:
    """Run configs, appending each finished trial to path; (trials run, elapsed seconds)."""
    from tqdm import tqdm
    writer = TrialWriter(path)
    if not configs:
        writer.close()
        return 0, 0.0
    t0 = time.perf_counter()
    n = 0
    try:
        with tqdm(total=len(configs), desc="grasp trials", unit="trial", disable=not progress or not configs) as bar:
            for _config, row in completed(run_trial, configs, failed_trial, scheduler, max_workers):
                writer.write(row)
                n += 1
                bar.update(1)
    finally:
        writer.close()
    return n, time.perf_counter() - t0


def study(xs=XS, ys=YS, trials: int = 1, mu_support=MEDIUM, mu_gripper=MEDIUM, seed: int = 0, h: float = gg.H,
          out: Path | str = DEFAULT_OUT, scheduler=None, max_workers=None, progress=True, fresh=False,
          plot=True) -> StudyResult:
    """Run the trials of the grid not yet in out/grasp_trials.csv, then summarise and plot all."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "grasp_trials.csv"
    if fresh and path.exists():
        path.unlink()
    configs = plan(xs, ys, trials, mu_support, mu_gripper, seed, h)
    tag = configs[0].settings
    # a trial that raised (a run error: a missing module on a Dask worker, a killed process) is not
    # a result: a resumed study runs it again, and its new row supersedes the old one
    done = {(r["x_mm"], r["y_mm"], r["trial"]) for r in read_trials(path)
            if r["settings"] == tag and r["kind"] != "run error"}
    todo = [c for c in configs if c.key not in done]
    workers = (os.cpu_count() or 1) if max_workers is None else max(int(max_workers), 1)
    ran, elapsed = execute(todo, path, scheduler, max_workers, progress)
    wanted = {c.key for c in configs}
    latest = {}
    for r in read_trials(path):
        if r["settings"] == tag and (r["x_mm"], r["y_mm"], r["trial"]) in wanted:
            key = (r["x_mm"], r["y_mm"], r["trial"])
            if r["kind"] != "run error" or latest.get(key, r)["kind"] == "run error":
                latest[key] = r          # a trial's last result counts; a run error only if it has none
    rows = list(latest.values())
    summary = summarise(rows, xs, ys)
    todo_keys = {c.key for c in todo}
    this_run = [r for r in rows if (r["x_mm"], r["y_mm"], r["trial"]) in todo_keys]
    summary["ran"] = ran
    summary["elapsed_s"] = elapsed
    summary["workers"] = 0 if scheduler else workers
    summary["trials_per_s"] = ran / elapsed if ran and elapsed > 0 else math.nan
    walls = [r["wall_s"] for r in this_run if math.isfinite(r["wall_s"])] or \
            [r["wall_s"] for r in rows if math.isfinite(r["wall_s"])]
    summary["wall_per_trial_s"] = float(np.mean(walls)) if walls else math.nan
    summary["trials_per_s_per_core"] = 1.0 / summary["wall_per_trial_s"] if walls else math.nan
    summary["settings"] = tag
    paths = {"trials": path, "cells": out / "grasp_cells.csv", "md": out / "grasp.md"}
    write_cells(summary, paths["cells"])
    if plot:
        paths["png"] = out / "grasp.png"
        plot_study(summary, paths["png"])
    paths["md"].write_text("\n".join(report_lines(summary)) + "\n")
    return StudyResult(rows, ran, elapsed, summary["workers"], summary, paths)


# ----------------------------------------------------------------------------------------------
# metrics
# ----------------------------------------------------------------------------------------------
def summarise(rows, xs=XS, ys=YS) -> dict:
    """Success probability per cell, failures by kind, the sweet spot and the plateau."""
    xs, ys = list(xs), list(ys)
    n = np.zeros((len(ys), len(xs)), int)
    s = np.zeros_like(n)
    kinds = {k: np.zeros_like(n) for k in KINDS}
    ix = {x: i for i, x in enumerate(xs)}
    iy = {y: j for j, y in enumerate(ys)}
    for r in rows:
        if r["x_mm"] in ix and r["y_mm"] in iy:
            j, i = iy[r["y_mm"]], ix[r["x_mm"]]
            n[j, i] += 1
            s[j, i] += r["success"]
            kinds[r["kind"] if r["kind"] in kinds else "run error"][j, i] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        prob = np.where(n > 0, s / np.maximum(n, 1), np.nan)
    # mirror about x = 0: columns -x_max..x_max (x = 0 once)
    mx = [-x for x in reversed(xs) if x > 0] + xs
    mprob = np.array([[prob[j, ix[abs(x)]] if abs(x) in ix else np.nan for x in mx] for j in range(len(ys))])
    sweet, box_mean = _sweet_spot(mprob, mx, ys)
    plateau = _plateau(mprob, mx, ys, sweet)
    paper_box = _box_mean(mprob, mx, ys, PAPER_SWEET_SPOT)
    band = [j for j, y in enumerate(ys) if PAPER_BAND[0] <= y <= PAPER_BAND[1]]
    return {"xs": xs, "ys": ys, "n": n, "successes": s, "probability": prob, "kinds": kinds,
            "mirrored_xs": mx, "mirrored": mprob, "sweet_spot": sweet, "sweet_box_mean": box_mean,
            "plateau": plateau, "paper_box_mean": paper_box,
            "paper_band_mean": float(np.nanmean(prob[band])) if band else math.nan,
            "trials": int(n.sum()), "overall": float(s.sum() / max(n.sum(), 1)),
            "by_kind": {k: int(v.sum()) for k, v in kinds.items()}}


def _box_mean(mprob, mx, ys, centre, half: int = SWEET_BOX) -> float:
    """Mean success over the (2 half + 1)^2 cells around centre; cells outside the grid or
    without trials count as failures (so a box hanging over the edge is not favoured)."""
    cx, cy = centre
    total = 0.0
    for y in range(int(cy) - half, int(cy) + half + 1):
        for x in range(int(cx) - half, int(cx) + half + 1):
            if y in ys and x in mx:
                v = mprob[ys.index(y), mx.index(x)]
                total += float(v) if np.isfinite(v) else 0.0
    return total / (2 * half + 1) ** 2


def _sweet_spot(mprob, mx, ys):
    best, best_key = None, None
    for j, y in enumerate(ys):
        for i, x in enumerate(mx):
            if x < 0 or not np.isfinite(mprob[j, i]):
                continue
            means = [round(_box_mean(mprob, mx, ys, (x, y), k), 12) for k in range(SWEET_BOX, 0, -1)]
            key = (*means, mprob[j, i], -abs(x))
            if best_key is None or key > best_key:
                best, best_key = (x, y), key
    return best, (best_key[0] if best_key else math.nan)


def _plateau(mprob, mx, ys, sweet) -> dict:
    empty = {"cells": 0, "x": (math.nan, math.nan), "y": (math.nan, math.nan), "members": []}
    if sweet is None:
        return empty
    i0, j0 = mx.index(sweet[0]), ys.index(sweet[1])
    high = np.nan_to_num(mprob, nan=0.0) >= PLATEAU_LEVEL
    if not high[j0, i0]:
        return empty
    seen, stack = {(j0, i0)}, [(j0, i0)]
    while stack:
        j, i = stack.pop()
        for dj, di in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            a, b = j + dj, i + di
            if 0 <= a < len(ys) and 0 <= b < len(mx) and high[a, b] and (a, b) not in seen:
                seen.add((a, b))
                stack.append((a, b))
    px = [mx[i] for _, i in seen]
    py = [ys[j] for j, _ in seen]
    return {"cells": len(seen), "x": (min(px), max(px)), "y": (min(py), max(py)),
            "members": sorted((mx[i], ys[j]) for j, i in seen)}


def write_cells(summary: dict, path: Path) -> None:
    with open(path, "w", newline="") as handle:
        w = csv.DictWriter(handle, fieldnames=CELL_FIELDS)
        w.writeheader()
        for j, y in enumerate(summary["ys"]):
            for i, x in enumerate(summary["xs"]):
                row = {"x_mm": x, "y_mm": y, "trials": int(summary["n"][j, i]),
                       "successes": int(summary["successes"][j, i]),
                       "probability": f"{summary['probability'][j, i]:.4g}"}
                for k in KINDS[1:]:
                    row[k.replace(" ", "_")] = int(summary["kinds"][k][j, i])
                w.writerow(row)


def report_lines(summary: dict) -> list[str]:
    p = summary["plateau"]
    sw = summary["sweet_spot"]
    lines = [
        "# Grasp study ([GI] Sec. 6.4, Fig. 10)",
        "",
        f"settings: {summary.get('settings', '')}",
        f"trials: {summary['trials']} over {len(summary['xs'])} x {len(summary['ys'])} cells; overall success "
        f"{summary['overall']:.3f}",
        "outcomes: " + ", ".join(f"{k} {v}" for k, v in summary["by_kind"].items()),
        f"sweet spot (best mean success over the +-{SWEET_BOX} mm box): ({sw[0]}, {sw[1]}) mm, box mean "
        f"{summary['sweet_box_mean']:.3f}" if sw else "sweet spot: none",
        f"plateau (success >= {PLATEAU_LEVEL}, 4-connected to the sweet spot, mirrored grid): {p['cells']} cells, "
        f"x {p['x'][0]}..{p['x'][1]} mm, y {p['y'][0]}..{p['y'][1]} mm",
        f"mean success in the +-{SWEET_BOX} mm box around the paper's sweet spot (0, -11): "
        f"{summary['paper_box_mean']:.3f}; in dVC's band y in [{PAPER_BAND[0]}, {PAPER_BAND[1]}] mm: "
        f"{summary['paper_band_mean']:.3f}",
    ]
    if summary.get("ran"):
        lines.append(f"this run: {summary['ran']} trials in {summary['elapsed_s']:.1f} s on "
                     f"{summary['workers'] or 'a Dask cluster of'} workers = {summary['trials_per_s']:.3f} trials/s; "
                     f"mean wall time per trial {summary['wall_per_trial_s']:.2f} s = "
                     f"{summary['trials_per_s_per_core']:.3f} trials/s per core")
    else:
        lines.append(f"no new trials (all resumed); mean wall time per trial {summary['wall_per_trial_s']:.2f} s = "
                     f"{summary['trials_per_s_per_core']:.3f} trials/s per core")
    lines += ["", "Success probability per cell (rows y, columns x = " +
              f"{summary['xs'][0]}..{summary['xs'][-1]} mm; '.' no trial):"]
    for j in reversed(range(len(summary["ys"]))):
        row = "".join(" ." if not np.isfinite(v) else f"{int(round(9 * v)):2d}" for v in summary["probability"][j])
        lines.append(f"  y={summary['ys'][j]:4d} {row}")
    lines.append("  (digits: 9 x probability, rounded)")
    return lines


# ----------------------------------------------------------------------------------------------
# figure
# ----------------------------------------------------------------------------------------------
def plot_study(summary: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import textwrap
    mx, ys, mprob = summary["mirrored_xs"], summary["ys"], summary["mirrored"]
    fig = plt.figure(figsize=(16, 6.0))
    grid = fig.add_gridspec(1, 3, width_ratios=(1.5, 1.2, 0.8))
    ax = fig.add_subplot(grid[0])
    im = ax.imshow(mprob, origin="lower", cmap="viridis", vmin=0, vmax=1, aspect="equal",
                   extent=(mx[0] - 0.5, mx[-1] + 0.5, ys[0] - 0.5, ys[-1] + 0.5))
    fig.colorbar(im, ax=ax, shrink=0.8, label="success probability")
    cx, cy = PAPER_SWEET_SPOT
    ax.add_patch(plt.Rectangle((cx - SWEET_BOX, cy - SWEET_BOX), 2 * SWEET_BOX, 2 * SWEET_BOX, fill=False,
                               ec="red", lw=1.5, label="paper: sweet spot +-3 mm"))
    ax.plot([cx], [cy], "r+", ms=12)
    ax.axhline(PAPER_BAND[0], color="w", ls="--", lw=0.8)
    ax.axhline(PAPER_BAND[1], color="w", ls="--", lw=0.8, label="dVC: success ~1 band")
    if summary["sweet_spot"]:
        sx, sy = summary["sweet_spot"]
        ax.plot([sx, -sx], [sy, sy], "o", mfc="none", mec="orange", ms=10, label="measured sweet spot")
    ax.set_xlabel("fingertip centre x [mm] (x < 0 mirrored)")
    ax.set_ylabel("fingertip centre y [mm]")
    ax.set_title(f"simulated success, {summary['trials']} trials")
    ax.legend(loc="upper right", fontsize=7)

    ax3 = fig.add_subplot(grid[1], projection="3d")
    xs, prob = summary["xs"], summary["probability"]
    X, Y = np.meshgrid(xs, ys)
    Z = np.nan_to_num(prob).ravel()
    ax3.bar3d(X.ravel() - 0.4, Y.ravel() - 0.4, np.zeros_like(Z), 0.8, 0.8, Z, shade=True,
              color=plt.cm.viridis(Z))
    ax3.set_xlabel("x [mm]"), ax3.set_ylabel("y [mm]"), ax3.set_zlabel("success")
    ax3.set_zlim(0, 1)
    ax3.view_init(elev=40, azim=-125)
    ax3.set_title("like [GI] Fig. 10b (half, x >= 0)")

    axt = fig.add_subplot(grid[2])
    axt.axis("off")
    p, sw = summary["plateau"], summary["sweet_spot"]
    measured = (f"Measured: sweet spot ({sw[0]}, {sw[1]}) mm (mean success {summary['sweet_box_mean']:.2f} over its "
                f"+-3 mm box); plateau (>= {PLATEAU_LEVEL}) x {p['x'][0]}..{p['x'][1]}, y {p['y'][0]}..{p['y'][1]} mm, "
                f"{p['cells']} cells; mean success in the paper's +-3 mm box {summary['paper_box_mean']:.2f}.")
    text = textwrap.fill(PAPER_FIG10A, 50) + "\n\n" + textwrap.fill(measured, 50)
    axt.text(0.0, 1.0, text, va="top", ha="left", fontsize=8.5, family="serif")
    axt.set_title("[GI] Fig. 10a, as described")
    fig.suptitle("Where should the jaws start to grasp the lock piece? Success probability per 1 mm cell")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------------------------
def _range(text: str) -> tuple[float, float]:
    lo, hi = (float(v) for v in text.split(","))
    return lo, hi


def _ints(text: str) -> tuple[int, ...]:
    lo, hi = (int(v) for v in text.split(","))
    return tuple(range(lo, hi + 1))


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=1, help="trials per cell (default 1; dVC used 25)")
    ap.add_argument("--mu-support", type=_range, default=MEDIUM, help="LO,HI (default 0.33,0.66)")
    ap.add_argument("--mu-gripper", type=_range, default=MEDIUM, help="LO,HI (default 0.33,0.66)")
    ap.add_argument("--x", type=_ints, default=XS, help="LO,HI cell x range [mm] (default 0,19)")
    ap.add_argument("--y", type=_ints, default=YS, help="LO,HI cell y range [mm] (default -19,-1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--h", type=float, default=gg.H, help=f"time step [s] (default {gg.H})")
    ap.add_argument("--workers", type=int, default=None, help="local processes (default: all cores; 0: in process)")
    ap.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--fresh", action="store_true", help="delete the results file first (default: resume)")
    ap.add_argument("--no-progress", action="store_true")
    return ap.parse_args(argv)


def main(argv=None) -> StudyResult:
    a = parse_args(argv)
    result = study(a.x, a.y, a.trials, a.mu_support, a.mu_gripper, a.seed, a.h, a.out, a.scheduler, a.workers,
                   progress=not a.no_progress, fresh=a.fresh)
    print("\n".join(report_lines(result.summary)))
    print("wrote " + ", ".join(str(p) for p in result.paths.values()))
    errors = [r for r in result.rows if r["kind"] == "run error"]
    if errors:
        print(f"{len(errors)} trials raised (run error), e.g. {errors[0]['reason']}; they are not results. "
              "Run the same command again to retry them.")
    return result


if __name__ == "__main__":
    raise SystemExit(1 if any(r["kind"] == "run error" for r in main().rows) else 0)
