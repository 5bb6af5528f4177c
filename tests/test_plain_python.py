"""The compiled kernels are plain Python: under NUMBA_DISABLE_JIT=1 (for debugging, see the README)
every scene steps through the same functions uncompiled and must give the compiled trajectory.

Each scene runs in a child process with the variable set (numba reads it at import) and prints
every skeleton's q and v after a few steps; this process runs the same steps compiled. Without
fastmath, LLVM keeps the order of the floating-point operations and the LAPACK calls are the
same, so the trajectories agree to round-off (measured: bit for bit).
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

AGREE = 1e-12          # |q, v| difference, compiled vs plain Python, after the steps below

SCENES = {
    # scene: (module, build_world arguments, steps, before each step)
    "rolling disc": ("disc_rolling", "(0.01)", 20, "pass"),
    "sphere on two spheres": ("sphere_on_two_spheres", "(0.01)", 20, "pass"),
    "quasi-rigid disc landing": ("disc_on_quasi_rigid_plane", "(1e-3, 2e-3)", 30, "pass"),
    # an articulated skeleton driven by joint forces, squeezing a box off the ground
    "parallel-jaw gripper": ("gripper_squeeze", "()", 40, "scene.control(built[1], world.getTime())"),
    # order 2 (rattle.py): its second stage's rows (rows/velocity.py) on a rocking ellipsoid
    "rocking ellipsoid, order 2": ("ellipsoid_rocking", "(2e-3)", 20, "pass", "ic.StepperOptions(order=2)"),
    # order 2 on a quasi-rigid layer (rattle.py, R11-R12): the disc lands at 0.32 s and hits the core
    "quasi-rigid disc landing, order 2": ("disc_on_quasi_rigid_plane", "(0.05, 0.012)", 32, "pass",
                                          "ic.StepperOptions(order=2)"),
}

PROGRAM = """
import json, sys
import implicit_contact as ic
from scenes import {module} as scene
built = scene.build_world{args}
world = built[0] if isinstance(built, tuple) else built
stepper = ic.ImplicitContactStepper(world, options={options})
for _ in range({steps}):
    {before}
    stepper.step()
print(json.dumps([world.getSkeleton(i).getPositions().tolist() + world.getSkeleton(i).getVelocities().tolist()
                  for i in range(world.getNumSkeletons())]))
"""


def _run(program: str, disable_jit: bool):
    env = dict(os.environ, NUMBA_DISABLE_JIT="1" if disable_jit else "0")
    root = Path(__file__).resolve().parents[1]
    env["PYTHONPATH"] = os.pathsep.join([str(root)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    done = subprocess.run([sys.executable, "-c", program], cwd=root, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return [np.asarray(s) for s in json.loads(done.stdout.strip().splitlines()[-1])]


@pytest.mark.parametrize("name", list(SCENES))
def test_scene_steps_the_same_uncompiled(name):
    module, args, steps, before, *options = SCENES[name]
    program = PROGRAM.format(module=module, args=args, steps=steps, before=before, options=(options or ["None"])[0])
    plain, compiled = _run(program, True), _run(program, False)
    assert len(plain) == len(compiled)
    moved = False
    for a, b in zip(plain, compiled):
        assert a.shape == b.shape and np.isfinite(a).all()
        np.testing.assert_allclose(a, b, rtol=0.0, atol=AGREE)
        moved |= a.size > 0 and np.abs(a).max() > 0.0
    assert moved


def test_every_kernel_module_is_hashed_for_the_cache():
    """_jit invalidates the cached kernels when the source of a module in KERNEL_MODULES changes
    (numba itself keys a cached kernel to its own file only): every module that defines kernels,
    or the bundle types they take, must be in the list."""
    from implicit_contact import _jit
    package = Path(_jit.__file__).parent
    defining = {str(p.relative_to(package)) for p in package.rglob("*.py")
                if any(tag in p.read_text() for tag in ("@kernel", "generator_kernel(", "StructRef"))}
    assert defining, "no kernel modules found"
    assert defining <= set(_jit.KERNEL_MODULES), sorted(defining - set(_jit.KERNEL_MODULES))
