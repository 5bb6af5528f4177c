"""comparisons.real_models.run_isolated: each model in its own process, so that a process that
dies (DART's own step segfaults in FCL on some example-robot-data models) costs its row only."""
import faulthandler
import os

from comparisons import real_models as rm


def _square(x, progress):
    progress[0], progress[1] = 3, 0
    return x * x


def _dies_in_dart(progress):
    progress[0], progress[1] = 917, 1       # 917 steps done, then in DART's step
    faulthandler._sigsegv()                 # a real SIGSEGV, as libfcl's null pointer gives


def _crashed(args, progress, exitcode):
    return ("crashed", args, int(progress[0]), progress[1], exitcode)


def test_a_process_that_dies_costs_its_own_row_only():
    rows = []
    jobs = [(_square, (2,)), (_dies_in_dart, ()), (_square, (5,)), (_square, (7,))]
    rm.run_isolated(jobs, 2, _crashed, rows.append)
    assert sorted(r for r in rows if not isinstance(r, tuple)) == [4, 25, 49]
    [crash] = [r for r in rows if isinstance(r, tuple)]
    assert crash[:4] == ("crashed", (), 917, 1.0)
    assert crash[4] != 0                    # -11 on POSIX: killed by the signal


def test_the_crash_row_says_where_the_process_died():
    root = "/robots-root"
    path = os.path.join(root, "robots", "g1_description", "urdf", "g1.urdf")
    row = rm._crashed_row((path, root, 1.0, 60.0), [917.0, 1.0], -11)
    assert row["model"] == "g1_description/urdf/g1.urdf" and row["steps"] == 917 and row["accepted"]
    assert row["failure"].startswith("CRASH") and "DART's own step" in row["failure"] and "-11" in row["failure"]
    loading = rm._crashed_row((path, root, 1.0, 60.0), [0.0, -1.0], -11)
    assert not loading["accepted"] and "loading the model" in loading["failure"]
