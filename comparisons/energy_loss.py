"""[GI] Fig. 1: how much kinetic energy does a rolling disc lose, in DART and in the implicit stepper?

Question. The disc of Example 1 (radius 1, m = 1, I_c = 0.5, mu = 0.4, q0 = [0, 1, 0],
v0 = [-3, 0, 3]) rolls without slipping and should keep KE = 6.75 J forever. DART can only give
it a polygonal shape; does refining the polygon (Fig. 1a) or the time step (Fig. 1b) bring its
energy back, and what does the geometrically implicit stepper do?

What is run (each run is one `RunConfig`, `run(config) -> RunRecord`):
  * stepper "dart_native": DART's own `world.step()` (collision detector + boxed LCP) on a
    regular N-gon prism, `comparisons.dart_native.build_ngon_world(N, h, detector)`;
    Fig. 1a: N in {10, 100, 1000, 10000} at h = 0.01 s; Fig. 1b: N = 1000 at
    h in {0.01, 0.005, 0.001, 0.0005, 0.0001} s; detector FCL (dartpy's default) unless
    `--detectors fcl,dart,bullet,ode` asks for more.
  * stepper "implicit": the implicit disc, `scenes.disc_rolling.simulate(duration, h)`, at every
    time step of the study (Fig. 1a: the flat line at h = 0.01 s).
  * stepper "exact": the rigid, perfectly inelastic, non-slipping rolling N-gon
    (`comparisons.dart_native.exact_ngon_kinetic_energy`), sampled every `Grid.exact_dt`.
    This is what an exact simulation of the *polygon* gives; only the true disc keeps 6.75 J.
    For N = 10 it does not apply with mu = 0.4 (the 10-gon would hop / needs mu >= 62), which the
    table and the legend say instead of drawing a line.

Horizons. By default every run goes to 5 s except the smallest steps (h < 1e-3 s: 5e-4 and
1e-4), which go to 1 s (their 5 s loss is "n/a"); `--full` runs everything to 5 s; `--quick`
is a smoke run (N in {100, 1000}, h in {0.01, 0.001}, 2 s).

Metrics. KE loss % = 100 (KE0 - KE(t)) / KE0 at t = 1 s and 5 s (negative: a gain); wall time
per step = total time in world.step() / stepper.step() over the run divided by its steps
(recording excluded), and its median. They differ a lot for FCL on fine polygons: FCL reports
no contact while the prism hops and hundreds of contacts when it lands (a 10000-gon: up to ~700),
and DART's LCP on those few landing steps takes most of the run's time (mean ~35 ms, median ~1 ms
per step). For DART runs the record also keeps the largest number of contacts in a step and the
share of steps without any contact (airborne). Runs share the machine's cores, so wall times vary
up to ~2x between invocations (see /work/shared/reference/dart_native.md).

Executors. The runs are independent: a local process pool (ProcessPoolExecutor, `--workers`,
default os.cpu_count(), "spawn" start so no forked dartpy/tqdm state) by default; `--workers 0`
runs them in this process; `--scheduler tcp://host:8786` sends them to a Dask cluster (optional
extra `cluster`; dask.distributed is imported only then): `dask scheduler` on one machine and
`dask worker tcp://host:8786` on each, in environments where this project is installed. The
study's own modules (scenes/, comparisons/) are uploaded to the scheduler and the workers when the
study connects (comparisons.executors.ship_checkout); the workers restart once to import them.
A run that raises is recorded as failed (note "run failed: ...") and the others go on; the
command then exits with status 1.

Outputs (in --out, default comparisons/out): energy_loss_N.png (Fig. 1a), energy_loss_h.png
(Fig. 1b), energy_loss.csv (one row per study and configuration), and a printed table and reading.

Run: python -m comparisons.energy_loss [--quick | --full] [--detectors fcl,dart,bullet,ode]
                                       [--workers N] [--scheduler tcp://...] [--out DIR]
"""
from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass, field, replace
import math
from pathlib import Path
import time

import numpy as np

from comparisons import dart_native
from implicit_contact.trajectory import simulate as simulate_stepper
from comparisons.executors import completed

STEPPERS = ("dart_native", "implicit", "exact")
STUDIES = ("N", "h")
STUDY_TITLES = {"N": "Fig. 1a, N sweep", "h": "Fig. 1b, h sweep"}
DEFAULT_OUT = Path(__file__).resolve().parent / "out"
KE0 = 6.75  # [J] 0.5 m |v0|^2 + 0.5 I_c omega0^2 of the paper's disc
LOSS_TIMES = (1.0, 5.0)  # [s] where the table reads the KE loss
CSV_FIELDS = ("study", "detector", "N", "h", "steps", "ke_loss_1s_percent", "ke_loss_5s_percent",
              "wall_us_per_step", "stepper", "duration_s", "max_rel_ke_change", "wall_us_median",
              "max_contacts", "airborne_percent", "note")
# Two curves "look alike" when their 5 s losses differ by less than this fraction of the larger.
ALIKE_FRACTION = 0.2
# A polygon rolling without lift-off touches the ground in every step; "it hops" when at least this
# share of its steps [%] has no contact (DART and Bullet: 0-15 %, FCL and ODE: 30-66 % measured).
HOPPING_PERCENT = 20.0


# ----------------------------------------------------------------------------------------------
# one run
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunConfig:
    """One independent simulation (hashable, picklable, so any executor can run it).

    stepper: one of STEPPERS; detector: one of dart_native.DETECTORS for "dart_native", "" else;
    n: polygon vertices (None for the implicit disc, a true circle); h: time step [s] (for
    "exact", the sampling interval of the recorded curve); duration: horizon [s].
    """

    stepper: str
    detector: str
    n: int | None
    h: float
    duration: float

    def __post_init__(self):
        if self.stepper not in STEPPERS:
            raise ValueError(f"stepper must be one of {STEPPERS}, got {self.stepper!r}")
        if self.stepper == "dart_native" and self.detector not in dart_native.DETECTORS:
            raise ValueError(f"detector must be one of {dart_native.DETECTORS}, got {self.detector!r}")
        if self.stepper != "dart_native" and self.detector:
            raise ValueError(f"only dart_native runs have a detector, got {self.detector!r} for {self.stepper}")
        if (self.stepper == "implicit") != (self.n is None):
            raise ValueError(f"n must be None exactly for the implicit disc, got n = {self.n!r} for {self.stepper}")
        if self.n is not None and not (isinstance(self.n, int) and self.n >= 3):
            raise ValueError(f"n must be an integer >= 3 (polygon vertices), got {self.n!r}")
        if not (math.isfinite(self.h) and self.h > 0):
            raise ValueError(f"h must be a finite time step > 0 [s], got {self.h!r}")
        if not (math.isfinite(self.duration) and self.duration >= self.h):
            raise ValueError(f"duration must be >= h [s], got {self.duration!r}")

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.h))

    @property
    def label(self) -> str:
        if self.stepper == "implicit":
            return f"implicit disc, h = {self.h:g} s"
        if self.stepper == "exact":
            return f"exact {self.n}-gon"
        return f"DART {self.detector.upper()} {self.n}-gon, h = {self.h:g} s"


@dataclass(frozen=True, eq=False)
class RunRecord:
    """What a run returns: KE(t) [J] at the recorded times [s] (every step; for "exact", every h),
    the mean and median wall time per step [us] (NaN for "exact"), for DART runs the largest
    number of contacts of a step and the % of steps without contact (else -1 and NaN), and a note
    (why a reference does not apply, or why a run failed; then times and kinetic are empty and
    applicable is False)."""

    config: RunConfig
    times: np.ndarray
    kinetic: np.ndarray
    wall_us_per_step: float
    wall_us_median: float = math.nan
    max_contacts: int = -1
    airborne_percent: float = math.nan
    applicable: bool = True
    note: str = ""

    def ke_loss_percent_at(self, t: float) -> float:
        """100 (KE0 - KE(t)) / KE0, NaN when the run did not reach t or has no curve."""
        if not self.applicable or t > self.times[-1] + 0.5 * self.config.h:
            return math.nan
        k = int(round(t / self.config.h))
        if abs(self.times[k] - t) > 1e-9 * max(1.0, t):
            raise ValueError(f"{self.config.label}: sample {k} is at {self.times[k]!r} s, expected {t!r} s")
        return float(dart_native.ke_loss_percent(self.kinetic[[0, k]])[1])

    @property
    def max_rel_ke_change(self) -> float:
        """max_t |KE(t) - KE0| / KE0 (NaN without a curve)."""
        if not self.applicable:
            return math.nan
        return float(np.max(np.abs(self.kinetic - self.kinetic[0])) / self.kinetic[0])


def run(config: RunConfig) -> RunRecord:
    """Simulate one configuration (a pure function of config: pool and Dask workers call it)."""
    if config.stepper == "exact":
        return _run_exact(config)
    contacts = {}
    if config.stepper == "implicit":
        from scenes import disc_rolling  # imports the implicit stepper only where it is used

        trajectory = disc_rolling.simulate(config.duration, config.h)
    else:
        world, _ = dart_native.build_ngon_world(config.n, h=config.h, detector=config.detector)
        trajectory = simulate_stepper(world, dart_native.DartNative(world), config.duration)
        counts = np.array([report.num_contacts for report in trajectory.reports])
        contacts = {"max_contacts": int(counts.max()), "airborne_percent": 100.0 * float(np.mean(counts == 0))}
    times, _, _, kinetic = trajectory.arrays()
    seconds = trajectory.step_seconds
    return RunRecord(config, times, kinetic, 1e6 * float(seconds.mean()), 1e6 * float(np.median(seconds)), **contacts)


def _run_exact(config: RunConfig) -> RunRecord:
    rolling = dart_native.exact_ngon_rolling(config.n, config.duration)
    if not rolling.applicable:
        return RunRecord(config, np.zeros(0), np.zeros(0), math.nan, applicable=False, note=rolling.reason)
    times = config.h * np.arange(config.steps + 1)
    return RunRecord(config, times, dart_native.exact_ngon_kinetic_energy(config.n, times), math.nan)


def _failed(config: RunConfig, error: BaseException) -> RunRecord:
    return RunRecord(config, np.zeros(0), np.zeros(0), math.nan, applicable=False,
                     note=f"run failed: {type(error).__name__}: {error}")


# ----------------------------------------------------------------------------------------------
# the grid of runs
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Grid:
    """What to run.

    sizes: N of Fig. 1a, at time step h_of_sizes [s]; steps: time steps [s] of Fig. 1b, at
    N = n_of_steps; detectors: DART detectors for the native runs; horizon [s]: duration of every
    run, except time steps below short_below [s], which run to short_horizon [s] (0 <= short_horizon
    <= horizon; short_below = 0 runs everything to horizon); exact_dt [s]: sampling interval of the
    exact reference (1e-3 resolves the 100-gon's 0.02 s pivots; finer polygons barely oscillate).
    """

    sizes: tuple[int, ...] = (10, 100, 1000, 10000)
    h_of_sizes: float = 0.01
    steps: tuple[float, ...] = (0.01, 0.005, 0.001, 0.0005, 0.0001)
    n_of_steps: int = 1000
    detectors: tuple[str, ...] = ("fcl",)
    horizon: float = 5.0
    short_horizon: float = 1.0
    short_below: float = 1e-3
    exact_dt: float = 1e-3

    def __post_init__(self):
        unknown = [d for d in self.detectors if d not in dart_native.DETECTORS]
        if not self.detectors or unknown:
            raise ValueError(f"detectors must be a non-empty subset of {dart_native.DETECTORS}, got {self.detectors!r}")
        if not (0 < self.short_horizon <= self.horizon):
            raise ValueError(f"need 0 < short_horizon <= horizon [s], got {self.short_horizon!r}, {self.horizon!r}")
        if not (self.sizes or self.steps):
            raise ValueError("the grid is empty: give sizes (Fig. 1a) or steps (Fig. 1b)")

    def duration(self, h: float) -> float:
        return self.horizon if h >= self.short_below else self.short_horizon


DEFAULT_GRID = Grid()
FULL_GRID = Grid(short_below=0.0)
QUICK_GRID = Grid(sizes=(100, 1000), steps=(0.01, 0.001), horizon=2.0, short_horizon=2.0)


def plan(grid: Grid) -> tuple[tuple[str, RunConfig], ...]:
    """(study, config) for every curve of both figures; a config can serve both studies."""
    entries = []
    if grid.sizes:
        duration = grid.duration(grid.h_of_sizes)
        for detector in grid.detectors:
            entries += [("N", RunConfig("dart_native", detector, n, grid.h_of_sizes, duration)) for n in grid.sizes]
        entries.append(("N", RunConfig("implicit", "", None, grid.h_of_sizes, duration)))
        entries += [("N", RunConfig("exact", "", n, grid.exact_dt, grid.horizon)) for n in grid.sizes]
    if grid.steps:
        for detector in grid.detectors:
            entries += [("h", RunConfig("dart_native", detector, grid.n_of_steps, h, grid.duration(h)))
                        for h in grid.steps]
        entries += [("h", RunConfig("implicit", "", None, h, grid.duration(h))) for h in grid.steps]
        longest = max(grid.duration(h) for h in grid.steps)
        entries.append(("h", RunConfig("exact", "", grid.n_of_steps, grid.exact_dt, longest)))
    return tuple(dict.fromkeys(entries))


def _cost(config: RunConfig) -> float:
    """Rough seconds of a run (measured magnitudes), only to start the longest runs first."""
    if config.stepper == "exact":
        return 0.1
    per_step = 1e-3 if config.stepper == "implicit" else 1e-4 + 3e-6 * config.n
    return config.steps * per_step


# ----------------------------------------------------------------------------------------------
# executors
# ----------------------------------------------------------------------------------------------
def execute(entries, scheduler: str | None = None, max_workers: int | None = None, progress: bool = True):
    """Run every distinct config of `entries` ((study, config) pairs) once; returns {config: record}.

    scheduler: a Dask scheduler address ("tcp://host:8786"), else a local process pool of
    max_workers processes (default os.cpu_count(); 0 runs in this process). A run that raises
    becomes a record with applicable = False and the error in its note; the others go on.
    One tqdm bar per study counts its finished runs.
    """
    from tqdm import tqdm

    studies_of: dict[RunConfig, list[str]] = {}
    for study, config in entries:
        studies_of.setdefault(config, []).append(study)
    configs = sorted(studies_of, key=_cost, reverse=True)
    totals = {s: sum(s in v for v in studies_of.values()) for s in STUDIES}
    bars = {s: tqdm(total=totals[s], desc=STUDY_TITLES[s], unit="run", position=i, disable=not progress or not totals[s])
            for i, s in enumerate(STUDIES)}
    records = {}
    try:
        for config, record in completed(run, configs, _failed, scheduler, max_workers):
            records[config] = record
            for study in studies_of[config]:
                bars[study].update()
    finally:
        for bar in bars.values():
            bar.close()
    return records


# ----------------------------------------------------------------------------------------------
# table, CSV, reading
# ----------------------------------------------------------------------------------------------
def rows(entries, records) -> list[dict]:
    """One row per (study, config), as CSV_FIELDS (NaN where not applicable)."""
    table = []
    for study, config in entries:
        record = records[config]
        native = config.stepper != "exact"
        table.append({
            "study": study,
            "detector": config.detector,
            "N": config.n,
            "h": config.h if native else None,
            "steps": config.steps if native else None,
            "ke_loss_1s_percent": record.ke_loss_percent_at(LOSS_TIMES[0]),
            "ke_loss_5s_percent": record.ke_loss_percent_at(LOSS_TIMES[1]),
            "wall_us_per_step": record.wall_us_per_step,
            "stepper": config.stepper,
            "duration_s": config.duration,
            "max_rel_ke_change": record.max_rel_ke_change,
            "wall_us_median": record.wall_us_median,
            "max_contacts": record.max_contacts if record.max_contacts >= 0 else None,
            "airborne_percent": record.airborne_percent,
            "note": record.note or ("" if native else f"continuous reference, sampled every {config.h:g} s"),
        })
    return table


def write_csv(table: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_FIELDS)
        writer.writeheader()
        for row in table:
            writer.writerow({k: _csv_value(row[k]) for k in CSV_FIELDS})


def _csv_value(value):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return f"{value:.6g}" if isinstance(value, float) else value


def format_table(table: list[dict]) -> str:
    """A fixed-width table per study: KE loss at 1 s / 5 s and wall time per step."""
    lines = []
    for study in STUDIES:
        chosen = [r for r in table if r["study"] == study]
        if not chosen:
            continue
        lines.append(f"\n{STUDY_TITLES[study]}: KE loss % = 100 (KE0 - KE) / KE0, KE0 = {KE0} J; wall time "
                     "per step [us], mean and median; DART: most contacts in a step, % of steps without contact")
        header = (f"{'stepper':<12} {'detector':<8} {'N':>6} {'h [s]':>7} {'steps':>6} {'loss 1 s':>9} "
                  f"{'loss 5 s':>9} {'us/step':>8} {'median':>7} {'contacts':>8} {'airborne':>8}  note")
        lines += [header, "-" * len(header)]
        for r in sorted(chosen, key=_table_order):
            n = "disc" if r["N"] is None else str(r["N"])
            h = "-" if r["h"] is None else f"{r['h']:g}"
            steps = "-" if r["steps"] is None else str(r["steps"])
            note = r["note"] or ("" if r["duration_s"] >= LOSS_TIMES[1] else f"run to {r['duration_s']:g} s")
            if r["stepper"] == "implicit":
                note = f"max |KE - KE0| / KE0 = {r['max_rel_ke_change']:.1e}" + (f"; {note}" if note else "")
            lines.append(f"{r['stepper']:<12} {r['detector'] or '-':<8} {n:>6} {h:>7} {steps:>6} "
                         f"{_cell(r['ke_loss_1s_percent']):>9} {_cell(r['ke_loss_5s_percent']):>9} "
                         f"{_cell(r['wall_us_per_step'], '.0f'):>8} {_cell(r['wall_us_median'], '.0f'):>7} "
                         f"{'-' if r['max_contacts'] is None else r['max_contacts']:>8} "
                         f"{'-' if r['max_contacts'] is None else format(r['airborne_percent'], '.0f') + ' %':>8}  {note}")
    return "\n".join(lines)


def _table_order(row):
    kind = STEPPERS.index(row["stepper"])
    return (kind, row["detector"], row["N"] or 0, -(row["h"] or 0.0))


def _cell(value, spec=".3g") -> str:
    return "n/a" if value is None or math.isnan(value) else format(value, spec)


def reading(table: list[dict]) -> list[str]:
    """A few sentences computed from the table (nothing here is hard-coded)."""
    def find(study, stepper, detector="", n=None, h=None):
        for r in table:
            if (r["study"], r["stepper"], r["detector"], r["N"]) == (study, stepper, detector, n) and (
                    h is None or r["h"] == h):
                return r
        return None

    def losses(r):
        parts = [f"{r[k]:.3g} % by {t:g} s" for k, t in zip(("ke_loss_1s_percent", "ke_loss_5s_percent"), LOSS_TIMES)
                 if not math.isnan(r[k])]
        return " and ".join(parts) if parts else "n/a"

    lines = []
    implicit = [r for r in table if r["stepper"] == "implicit" and not math.isnan(r["max_rel_ke_change"])]
    if implicit:
        worst = max(implicit, key=lambda r: r["max_rel_ke_change"])
        lines.append(f"Implicit disc: max |KE - KE0| / KE0 = {worst['max_rel_ke_change']:.1e} over "
                     f"{len({r['h'] for r in implicit})} time step(s) (worst at h = {worst['h']:g} s): it keeps {KE0} J.")
    failed = [r for r in table if r["note"].startswith("run failed")]
    for r in failed:
        lines.append(f"FAILED: {r['stepper']} {r['detector']} N = {r['N']} h = {r['h']}: {r['note']}")
    sizes = sorted({r["N"] for r in table if r["study"] == "N" and r["stepper"] == "dart_native"})
    h_n = next((r["h"] for r in table if r["study"] == "N" and r["stepper"] == "dart_native"), None)
    for detector in dict.fromkeys(r["detector"] for r in table if r["stepper"] == "dart_native"):
        if 1000 in sizes and (native := find("N", "dart_native", detector, 1000)):
            exact = find("N", "exact", "", 1000)
            text = f"{detector.upper()} 1000-gon at h = {h_n:g} s loses {losses(native)}"
            if exact and not math.isnan(exact["ke_loss_5s_percent"]) and not math.isnan(native["ke_loss_5s_percent"]):
                ratio = native["ke_loss_5s_percent"] / exact["ke_loss_5s_percent"]
                text += f"; the exact rolling 1000-gon loses {losses(exact)} ({ratio:.2g}x that by 5 s"
                text += ", so DART misses vertex impacts)" if ratio < 1.0 else ")"
            airborne = native["airborne_percent"]
            text += (f"; {airborne:.0f} % of its steps have no contact" + (" (it hops)" if airborne >= HOPPING_PERCENT else "")
                     + f" and a step has at most {native['max_contacts']} contacts")
            lines.append(text + ".")
        coarse, fine = (find("N", "dart_native", detector, n) for n in (1000, 10000))
        if coarse and fine:
            key = "ke_loss_5s_percent" if not math.isnan(coarse["ke_loss_5s_percent"]) else "ke_loss_1s_percent"
            a, b = coarse[key], fine[key]
            alike = abs(a - b) <= ALIKE_FRACTION * max(abs(a), abs(b))
            lines.append(f"{detector.upper()} N = 1000 vs 10000 at h = {h_n:g} s: {a:.3g} % vs {b:.3g} % by "
                         f"{5 if key.endswith('5s_percent') else 1} s: "
                         + ("they look alike; a finer polygon does not bring the energy back."
                            if alike else "they differ."))
        sweep = sorted((r for r in table if r["study"] == "h" and r["stepper"] == "dart_native"
                        and r["detector"] == detector), key=lambda r: -r["h"])
        exact_h = next((r for r in table if r["study"] == "h" and r["stepper"] == "exact"), None)
        if len(sweep) >= 2 and exact_h:
            lines.append(f"{detector.upper()} {exact_h['N']}-gon, h from {sweep[0]['h']:g} to {sweep[-1]['h']:g} s: "
                         f"loss by 1 s {sweep[0]['ke_loss_1s_percent']:.3g} % -> {sweep[-1]['ke_loss_1s_percent']:.3g} %; "
                         f"exact {exact_h['N']}-gon {exact_h['ke_loss_1s_percent']:.3g} %"
                         + _approach(sweep[0]["ke_loss_1s_percent"], sweep[-1]["ke_loss_1s_percent"],
                                     exact_h["ke_loss_1s_percent"]))
    for r in table:
        if r["study"] == "N" and r["stepper"] == "exact" and r["note"] and not r["note"].startswith(("continuous", "run failed")):
            lines.append(f"Exact {r['N']}-gon: n/a, {r['note']}.")
    timed = find("N", "dart_native", "fcl", 1000) or find("h", "dart_native", "fcl", 1000, 0.01)
    implicit_01 = next((r for r in implicit if timed and r["h"] == timed["h"]), None)
    if timed and implicit_01:
        lines.append(f"Wall time per step at h = {timed['h']:g} s, mean (median), runs sharing the cores: implicit "
                     f"disc {implicit_01['wall_us_per_step']:.0f} ({implicit_01['wall_us_median']:.0f}) us, DART FCL "
                     f"1000-gon {timed['wall_us_per_step']:.0f} ({timed['wall_us_median']:.0f}) us.")
    return lines


def _approach(coarse: float, fine: float, exact: float) -> str:
    if abs(fine - exact) <= 0.25 * abs(coarse - exact):
        return ": the smallest step approaches the exact polygon, which still loses energy at every vertex."
    return "."


# ----------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------
def plot_study(study: str, entries, records, path: Path, grid: Grid) -> None:
    """KE [J] vs time [s], one panel per detector: DART runs solid, exact polygons dashed in the
    same colour (or a legend-only "n/a" entry), the implicit disc black."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chosen = [c for s, c in entries if s == study]
    detectors = list(dict.fromkeys(c.detector for c in chosen if c.stepper == "dart_native"))
    columns = min(2, len(detectors))
    rows_ = math.ceil(len(detectors) / columns)
    fig, axes = plt.subplots(rows_, columns, figsize=(6.4 * columns, 3.4 * rows_ + 1.4), squeeze=False,
                             sharex=True, sharey=True, layout="constrained")
    varied = sorted({c.n for c in chosen if c.stepper == "dart_native"}) if study == "N" else \
        sorted({c.h for c in chosen if c.stepper == "dart_native"}, reverse=True)
    colours = dict(zip(varied, plt.get_cmap("viridis")(np.linspace(0.0, 0.85, max(len(varied), 1)))))
    for ax, detector in zip(axes.flat, detectors):
        for config in chosen:
            record = records[config]
            if config.stepper == "dart_native" and config.detector == detector:
                key = config.n if study == "N" else config.h
                label = f"DART {config.n}-gon" if study == "N" else f"DART 1000-gon, h = {config.h:g} s"
                _plot(ax, record, colour=colours[key], label=label, lw=1.2)
            elif config.stepper == "exact":
                colour = colours.get(config.n, "0.4") if study == "N" else "0.4"
                if record.applicable:
                    _plot(ax, record, colour=colour, label=f"exact rolling {config.n}-gon", ls="--", lw=1.2)
                else:
                    need = dart_native.exact_ngon_rolling(config.n, config.duration).required_mu
                    ax.plot([], [], " ", label=f"exact {config.n}-gon: n/a (needs mu >= {need:.2g}; mu = 0.4)")
        implicit = [c for c in chosen if c.stepper == "implicit"]
        for k, config in enumerate(implicit):
            label = "implicit disc (this package)" if len(implicit) == 1 else \
                ("implicit disc, every h (lines overlap)" if k == 0 else None)
            # below the DART lines, which end near 6.7 J at the smallest steps and would hide under it
            _plot(ax, records[config], colour="black", label=label, lw=2.0, zorder=1.5)
        ax.set_title(f"detector: {detector.upper()}" + (" (dartpy default)" if detector == "fcl" else ""), fontsize=10)
        ax.set_ylim(0.0, 1.08 * KE0)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("kinetic energy [J]")
    for ax in list(axes.flat)[len(detectors):]:
        ax.set_visible(False)
    question = (f"Does a finer polygon keep the rolling disc's energy in DART? (h = {grid.h_of_sizes:g} s)"
                if study == "N" else f"Does a smaller time step keep the {grid.n_of_steps}-gon's energy in DART?")
    fig.suptitle(question)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot(ax, record: RunRecord, colour, label, **style):
    if not record.applicable:
        ax.plot([], [], " ", label=f"{label}: {record.note}")
        return
    ax.plot(record.times, record.kinetic, color=colour, label=label, **style)


# ----------------------------------------------------------------------------------------------
# the study
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StudyResult:
    table: list = field(default_factory=list)
    records: dict = field(default_factory=dict)
    paths: dict = field(default_factory=dict)
    reading: list = field(default_factory=list)
    seconds: float = 0.0


def study(grid: Grid = DEFAULT_GRID, out: Path | str = DEFAULT_OUT, scheduler: str | None = None,
          max_workers: int | None = None, progress: bool = True) -> StudyResult:
    """Run the grid, write energy_loss.csv and one PNG per study present into out, return all."""
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    entries = plan(grid)
    records = execute(entries, scheduler=scheduler, max_workers=max_workers, progress=progress)
    table = rows(entries, records)
    paths = {"csv": out / "energy_loss.csv"}
    write_csv(table, paths["csv"])
    for name in STUDIES:
        if any(s == name for s, _ in entries):
            paths[name] = out / f"energy_loss_{name}.png"
            plot_study(name, entries, records, paths[name], grid)
    return StudyResult(table, records, paths, reading(table), time.perf_counter() - start)


def parse_args(argv=None) -> tuple[argparse.Namespace, Grid]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="smoke run: N in {100, 1000}, h in {0.01, 0.001}, 2 s")
    mode.add_argument("--full", action="store_true", help="every run to 5 s (default: h < 1e-3 only to 1 s)")
    parser.add_argument("--detectors", default="fcl",
                        help=f"comma-separated subset of {','.join(dart_native.DETECTORS)} (default: fcl)")
    parser.add_argument("--workers", type=int, default=None,
                        help="local processes (default: os.cpu_count(); 0 = run in this process)")
    parser.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    args = parser.parse_args(argv)
    detectors = tuple(d.strip().lower() for d in args.detectors.split(",") if d.strip())
    base = QUICK_GRID if args.quick else FULL_GRID if args.full else DEFAULT_GRID
    try:
        grid = replace(base, detectors=detectors)
    except ValueError as error:
        parser.error(str(error))
    return args, grid


def main(argv=None) -> StudyResult:
    args, grid = parse_args(argv)
    result = study(grid, args.out, scheduler=args.scheduler, max_workers=args.workers)
    print(format_table(result.table))
    print("\nReading:")
    for line in result.reading:
        print(f"  * {line}")
    print("\nwrote " + ", ".join(str(p) for p in result.paths.values()))
    print(f"total wall time {result.seconds:.1f} s")
    return result


if __name__ == "__main__":
    # Run the imported module rather than __main__, so that pickled configs and `run` are named
    # comparisons.energy_loss, which pool and Dask workers can import.
    from comparisons.energy_loss import main as _main

    raise SystemExit(1 if any(r["note"].startswith("run failed") for r in _main().table) else 0)
