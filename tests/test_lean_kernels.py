"""The kernels compiled without numba's runtime (_jit.lean_kernel) keep its two rules.

A lean kernel keeps no reference counts, so an array view it hands to a kernel with the runtime
would be released once too often. Rule 1: it returns no array, except to other lean kernels
(ALLOWED_ARRAY_RETURNS, each with the reason). Rule 2: it allocates nothing (numba refuses to
compile an allocation there; checked here by compiling every lean kernel the step uses). Both are
read from the compiled signatures after a few steps of scenes that reach every row kernel: a rigid
3D pair with friction and torsion, a 2D pair, a quasi-rigid layer, an articulated skeleton, order
2's second stage and a sparse many-body solve with the closest-point blocks eliminated.
"""
import ast
import importlib
import inspect
import pkgutil
import textwrap

import numba
import pytest
from numba.core import types

import implicit_contact as ic

# lean kernels that return views of their workspace; every caller is itself a lean kernel
ALLOWED_ARRAY_RETURNS = {
    "implicit_contact.rows.contact._take": "workspace slices, taken only inside contact.py's lean kernels",
}


def _lean_dispatchers():
    found = {}
    modules = [importlib.import_module(m.name) for m in pkgutil.walk_packages(ic.__path__, "implicit_contact.")
               if m.name not in ("implicit_contact.animate",)]
    for module in modules:
        for name, obj in vars(module).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher) and obj.__module__ == module.__name__:
                if obj.targetoptions.get("_nrt") is False:
                    found[f"{module.__name__}.{name}"] = obj
    return found


def _holds_array(ty) -> bool:
    if isinstance(ty, types.Array):
        return True
    if isinstance(ty, (types.BaseTuple,)):
        return any(_holds_array(t) for t in ty.types)
    return False


@pytest.fixture(scope="module")
def stepped():
    from comparisons import stability
    from scenes import disc_on_quasi_rigid_plane, ellipsoid_rocking, gripper_squeeze, sphere_on_two_spheres
    from implicit_contact import step_solver

    runs = [(sphere_on_two_spheres.build_world(0.01), 5, ic.StepperOptions()),
            (ellipsoid_rocking.build_world(2e-3), 5, ic.StepperOptions(order=2)),
            (disc_on_quasi_rigid_plane.build_world(1e-3, 2e-3), 30, ic.StepperOptions())]
    grip = gripper_squeeze.build_world()
    for world, steps, options in runs:
        stepper = ic.ImplicitContactStepper(world, options=options)
        for _ in range(steps):
            stepper.step()
    world = grip[0] if isinstance(grip, tuple) else grip
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(10):
        gripper_squeeze.control(grip[1], world.getTime())
        stepper.step()
    assert step_solver.ELIMINATE_MIN_UNKNOWNS <= 800
    world = stability.many_bodies_world(27, 0.01, stability.IMPLICIT)
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(14):                  # the first landings: sparse solves of ~500 unknowns
        stepper.step()
    return _lean_dispatchers()


def test_the_hot_row_kernels_are_lean(stepped):
    for name in ("implicit_contact.rows.contact.pair_rows", "implicit_contact.rows.assemble.assemble",
                 "implicit_contact.shape_kernels.evaluate", "implicit_contact.sparse_lu.factor"):
        assert name in stepped


def test_lean_kernels_called_from_python_return_no_array(stepped):
    """Rule 1 on the compiled signatures this process holds (a kernel loaded from the cache and
    called only by other kernels has none here, hence the static test below)."""
    compiled = 0
    for name, dispatcher in stepped.items():
        for signature in dispatcher.nopython_signatures:
            compiled += 1
            if _holds_array(signature.return_type):
                assert name in ALLOWED_ARRAY_RETURNS, f"{name} returns {signature.return_type}"
    assert compiled >= 5             # the scenes above called lean kernels from Python


def _array_like(node, arrays) -> bool:
    """Whether an expression is, or holds, a view: a parameter or a name bound to a view, a
    subscript, a reshape or transpose, or a call of an allowed array-returning kernel."""
    if isinstance(node, ast.Name):
        return node.id in arrays
    if isinstance(node, ast.Subscript):
        return _array_like(node.value, arrays) or isinstance(node.slice, ast.Slice)
    if isinstance(node, ast.Attribute):
        return node.attr in ("T", "reshape") or _array_like(node.value, arrays)
    if isinstance(node, ast.Call):
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
        return name in ("reshape", "ravel") or any(name == k.rsplit(".", 1)[1] for k in ALLOWED_ARRAY_RETURNS)
    if isinstance(node, (ast.Tuple, ast.List)):
        return any(_array_like(e, arrays) for e in node.elts)
    return False


def test_lean_kernels_return_no_view_statically(stepped):
    """Rule 1 from the source: no lean kernel returns an array parameter (one it indexes), a
    slice, a reshape or a name bound to one of those."""
    checked = 0
    for name, dispatcher in stepped.items():
        tree = ast.parse(textwrap.dedent(inspect.getsource(dispatcher.py_func)))
        fn = tree.body[0]
        params = {a.arg for a in fn.args.args}
        arrays = {n.value.id for n in ast.walk(fn) if isinstance(n, (ast.Subscript, ast.Attribute))
                  and isinstance(n.value, ast.Name) and n.value.id in params}    # the array parameters
        for node in ast.walk(fn):            # names bound to views (one pass suffices for these kernels)
            if isinstance(node, ast.Assign) and _array_like(node.value, arrays):
                for target in node.targets:
                    for t in (target.elts if isinstance(target, ast.Tuple) else [target]):
                        if isinstance(t, ast.Name):
                            arrays.add(t.id)
        views = [ast.unparse(node) for node in ast.walk(fn)
                 if isinstance(node, ast.Return) and node.value is not None and _array_like(node.value, arrays)]
        if name in ALLOWED_ARRAY_RETURNS:
            assert views, f"{name} is allowed to return a view and the check does not see it"   # it can fail
        else:
            assert not views, f"{name} may return a view: {views}"
        checked += 1
    assert checked >= 30


def _callee(node, namespace):
    """The object a call's function names in a kernel's module namespace (None if unknown)."""
    f = node.func
    if isinstance(f, ast.Name):
        return namespace.get(f.id)
    if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name):
        owner = namespace.get(f.value.id)
        return getattr(owner, f.attr, None) if owner is not None else None
    return None


def _kernel_calls(dispatcher):
    """[(callee dispatcher, whether it is lean)] of the kernels a kernel's source calls."""
    namespace = dispatcher.py_func.__globals__
    fn = ast.parse(textwrap.dedent(inspect.getsource(dispatcher.py_func))).body[0]
    out = []
    for node in ast.walk(fn):
        if isinstance(node, ast.Call):
            callee = _callee(node, namespace)
            if isinstance(callee, numba.core.registry.CPUDispatcher):
                out.append((callee, callee.targetoptions.get("_nrt") is False))
    return out


def test_lean_kernels_call_only_lean_kernels(stepped):
    """Rule 2's consequence: numba compiles a kernel called from a lean kernel with the caller's
    missing runtime when it has not been compiled already (its own options do not set it), so a
    callee that allocates or reads a StructRef fails to compile there, in an order-dependent way
    (measured: ncp.dense_newton's np.empty under a lean ncp.dense_request; step_kernels'
    bundles under a lean kinematics). Checked on the source: every kernel a lean kernel calls,
    resolved in its module, is lean."""
    from implicit_contact import ncp

    assert any(not lean for _, lean in _kernel_calls(ncp.dense_request))      # the check can fail
    calls = 0
    for name, dispatcher in stepped.items():
        for callee, lean in _kernel_calls(dispatcher):
            calls += 1
            assert lean, f"{name} calls {callee.py_func.__module__}.{callee.__name__}, a kernel with the runtime"
    assert calls >= 20
