"""Bundles of arrays handed to a compiled kernel as one argument (numba StructRefs).

A call from Python into a compiled kernel costs about 0.07 us per array argument to type and
unbox; the step that repeats the last one's structure (repeat_kernels.step) reads some hundred
arrays. Bundled into a few StructRefs it costs one argument each. A bundle holds the same
arrays as the Python objects that made it (numba keeps references to their memory), so what
Python writes into them the kernel reads, and the other way round; a field is never rebound.

Under NUMBA_DISABLE_JIT=1 a bundle is a types.SimpleNamespace with the same fields, which the
kernels, then plain Python, read the same way.
"""
from __future__ import annotations

import inspect
import types as _pytypes

import numba
from numba import types
from numba.experimental import structref

from ._jit import kernel


@structref.register
class WorldType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


@structref.register
class TablesType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


@structref.register
class SolverType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


@structref.register
class ContextType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class World(structref.StructRefProxy):
    """The stepper's world tables and buffers (stepper._World)."""


class Tables(structref.StructRefProxy):
    """A step problem's tables and evaluation workspace (formulation.StepProblem)."""


class Solver(structref.StructRefProxy):
    """One set of solver buffers (ncp.Buffers, J, H) and its options array."""


class Context(structref.StructRefProxy):
    """What _repeat_step compares and fills (stepper._Context)."""


@structref.register
class RepeatType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class Repeat(structref.StructRefProxy):
    """The five bundles repeat_kernels.step reads (World, Tables, its Solver and polishing Solver,
    Context), as one argument: unboxing a bundle costs ~0.5 us a call, five of them 2.5 us (~5 %
    of the rolling disc's step), one holding them 0.7 us."""


# The constructors, compiled and cached like every kernel. numba's own proxy constructor
# (StructRefProxy.__new__) is an uncached njit function, compiled afresh in every process for
# each bundle: ~1.5-6 s per process before its first step (measured: 5.1 s of the first grasp
# trial's 5.9 s in a fresh worker). Their parameters are the bundles' fields.
@kernel
def new_world(
        sk_nv, sk_voff, sk_moff, bd_kind, bd_sk, bd_joff, ob_body, ob_bounded, ob_dim, ob_centre, ob_half,
        ob_reach, ob_radius, exact_lo, exact_hi, is_mobile, fixed, read_bodies, Q, V, TAU, FEXT, CG, MB, FB,
        VF, JB, TG, R_given, p_given, R_now, p_now, th_now, R_pred, p_pred, th_pred, R_half, p_half, th_half,
        margins, glo, ghi, R_fixed, p_fixed, SPK, SPD, SPQ0, V_solved, DV_solved):
    return World(
        sk_nv, sk_voff, sk_moff, bd_kind, bd_sk, bd_joff, ob_body, ob_bounded, ob_dim, ob_centre, ob_half,
        ob_reach, ob_radius, exact_lo, exact_hi, is_mobile, fixed, read_bodies, Q, V, TAU, FEXT, CG, MB, FB,
        VF, JB, TG, R_given, p_given, R_now, p_now, th_now, R_pred, p_pred, th_pred, R_half, p_half, th_half,
        margins, glo, ghi, R_fixed, p_fixed, SPK, SPD, SPQ0, V_solved, DV_solved)


@kernel
def new_tables(
        body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f, loc_idx,
        loc_off, scale, body_dim, pos_rows, sup_body, sup_c, sup_er, sup_mun, lower, upper, rep, st_R, st_p,
        st_w, st_vo, st_T, FL, JL, ws):
    return Tables(
        body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f, loc_idx,
        loc_off, scale, body_dim, pos_rows, sup_body, sup_c, sup_er, sup_mun, lower, upper, rep, st_R, st_p,
        st_w, st_vo, st_T, FL, JL, ws)


@kernel
def new_solver(
        x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf, work, J, H, opt):
    return Solver(
        x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf, work, J, H, opt)


@kernel
def new_context(
        cand, near, far, far_P, far_g, gaps, eligible, flags, near_gaps, left, z0, sup_y, src, J_at, h_body,
        sk_src, identity):
    return Context(
        cand, near, far, far_P, far_g, gaps, eligible, flags, near_gaps, left, z0, sup_y, src, J_at, h_body,
        sk_src, identity)


@kernel
def new_repeat(W, T, S, SP, C):
    return Repeat(W, T, S, SP, C)


def _fields(ctor) -> tuple:
    return tuple(inspect.signature(getattr(ctor, "py_func", ctor)).parameters)


WORLD_FIELDS, TABLE_FIELDS = _fields(new_world), _fields(new_tables)
SOLVER_FIELDS, CONTEXT_FIELDS = _fields(new_solver), _fields(new_context)
REPEAT_FIELDS = _fields(new_repeat)

structref.define_proxy(World, WorldType, list(WORLD_FIELDS))
structref.define_proxy(Tables, TablesType, list(TABLE_FIELDS))
structref.define_proxy(Solver, SolverType, list(SOLVER_FIELDS))
structref.define_proxy(Context, ContextType, list(CONTEXT_FIELDS))
structref.define_proxy(Repeat, RepeatType, list(REPEAT_FIELDS))


def _make(ctor, fields, values: dict):
    missing = [f for f in fields if f not in values]
    if missing:
        raise ValueError(f"{ctor.__name__} needs {missing}")
    if numba.config.DISABLE_JIT:
        return _pytypes.SimpleNamespace(**{f: values[f] for f in fields})
    return ctor(*[values[f] for f in fields])


def world(**values):
    return _make(new_world, WORLD_FIELDS, values)


def tables(**values):
    return _make(new_tables, TABLE_FIELDS, values)


def solver(**values):
    return _make(new_solver, SOLVER_FIELDS, values)


def context(**values):
    return _make(new_context, CONTEXT_FIELDS, values)


def repeat(**values):
    return _make(new_repeat, REPEAT_FIELDS, values)
