"""The compiled step loop: one run of time steps in one numba call, the same stages for every compiled path.

Per step, with fixed stages:
1. predict -- the base node kinematics imposed from the packed base motion (eqs. 18-19), the predictor of the
   attempt (``newton.predict``);
2. assemble -- the internal forces and the contributions' forces and Jacobians (``newton.newton``);
3. Newton with one retry policy: the extrapolating predictor first while it works, then q_n (predictor choice and
   budgets as :meth:`~needle_sim_ros.model.integrators.Integrator.step`); a step that does not converge ends the
   run, the caller integrates it with the general path (sub-stepping, errors) and continues;
4. commit -- the state accepted and the contributions' states advanced (``advance``);
5. reaction -- the base wrench (eq. 20) under the contributions' forces of the next step (evaluated only where
   they act on the base element's rows).

A contribution is the state the loop carries (any numba value: a named tuple of arrays, or its constants) and
six compiled kernels (:class:`Kernels`), or parts of such (:func:`parts_of`: the tissue); :func:`compiled_run` makes
the module-level-like entry that inlines ``run_steps`` with every part's kernels, one level (the kernels are
compile-time constants there; each entry is made once per process and cached on disk like any other), and
:func:`compose` the same parts' functions on packed arrays for the general path:
* ``load(state, constants) -> carried`` and ``store(carried) -> state``: the carried state from the packed state
  and constants (float64 arrays: numba 0.59 types a tuple argument in Python on every call) and back;
* ``acting(carried) -> forces``: what acts over the step starting from the state (only what ``assemble`` reads:
  it is passed to every correction);
* ``assemble(forces, q, qd, rotation, Q, band, kl, c_q, c_qd) -> bool``: adds its generalized force to Q and, if
  ``band`` is not (0, 0), c_q dQ/dq + c_qd dQ/dq' to the band matrix; False if it cannot be assembled;
* ``advance(carried, q, qd, t) -> carried``: the state after a step accepted at (q, q', t);
* ``touches_base(forces) -> bool``: whether the forces act on the base element's rows (the reaction needs them).
With no state-dependent contribution (``keep_matrix``) the iteration matrix is kept across steps while the base
holds still and the steps converge in a single correction: then no matrix is assembled or factored at all (a
needle held still under a load: 22 instead of 40 us per step). Otherwise a step starts with a fresh matrix: chord
corrections on an older matrix converge slowly (released from a 10 g tip load: 4.2 corrections per step instead
of 2.1; pitching base: 3.0 instead of 1.1). The cost of each stage: ``bench/bench_step_stages.py`` (README).
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import tempfile
import types
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np
from numba import njit

from .kinematics import rigid_node_kinematics
from .newton import (CONVERGED, element_work, keeps_extrapolating, newton, no_forces, predictor_budget,
                     predictor_for_attempt, unpack_tables)
from .reaction import base_wrench_kernel

EXTRAPOLATE, FACTORED = 0, 1  # entries of the control flags


@njit(cache=True)
def base_tables(tables):
    """``reaction.base_rows`` from the model tables: element 0's quadrature tables and the base slots' rows."""
    (axial_S_x, axial_weights, bending_S_x, bending_S_xx, bending_weights, mass_slots, damping_isotropic,
     damping_transverse, strain_rate_weights) = unpack_tables(tables)
    return (axial_S_x[:1], axial_weights[:1], bending_S_x[:1], bending_S_xx[:1], bending_weights[:1],
            strain_rate_weights[:1], mass_slots[:2, :4], damping_isotropic[:2, :4], damping_transverse[:2, :4])


@njit(inline="always")
def solve_step(values, current, prescribed, axis, rotation, constant_Q, ext_Q, solver, work, control, keep_matrix,
               moved, forces, assemble):
    """Stages 2-3 of a step from ``current`` (rows q, q', q'', a) to ``values`` with the constrained rows
    ``prescribed``: assemble and Newton with the one retry policy, the extrapolating predictor first while it works,
    then q_n (``solver``, ``work``: see :func:`run_steps`). Returns (status, Newton corrections, last scaled
    correction)."""
    coef, tol, max_iterations, active, scale, tables, kl = solver
    residual, band, ext_band, pivots, factorization = work
    total, status, norm = 0, -1, np.inf
    for attempt in range(2):
        predictor = predictor_for_attempt(attempt, control[EXTRAPOLATE] == 1)
        budget = predictor_budget(predictor, max_iterations)
        fresh = not keep_matrix or control[FACTORED] == 0 or moved
        status, used, norm = newton(values, current, prescribed, coef, True, predictor, active, scale, tables, axis,
                                    constant_Q, ext_Q, residual, band, ext_band, pivots, factorization, kl, tol,
                                    budget, False, fresh, assemble, forces, rotation)
        total += used
        if keep_matrix:
            control[FACTORED] = 1 if status != -1 else 0
        if status == CONVERGED:
            control[EXTRAPOLATE] = 1 if keeps_extrapolating(predictor, used) else 0
            break
    return status, total, norm


@njit(inline="always")
def run_steps(history, times, motions, rotations, constant_Q, held_Q, solver, base, work, control, last_motion,
              keep_matrix, state, acting, assemble, advance, touches_base, outputs):
    """Integrate from history (rows q, q', q'', a at t_n) one step per end time (k,) and packed base motion
    (k, 19) with rotations (k, 3, 3) (module docstring). Every assembly starts from ``constant_Q``: the constant
    force, or zero where ``assemble`` adds the constant itself; ``held_Q`` is the constant force (the reaction's
    where the contributions do not act on the base element). ``solver``: (scheme coefficients, tolerance, iteration
    limit, active mask, scales, model tables, bandwidth); ``base``: (prescribed rows, base nodes, their local
    offsets r and r_x); ``work``: (residual, band, ext_band, pivots, factorization). ``control`` [extrapolate,
    factored] and ``last_motion`` (the motion the kept factorization in ``band`` was made for) carry over between
    runs. Writes each step's rows into the outputs' states (k, 4, n), its wrench on the holder [force, torque in
    the world frame, force, torque in the base frame] into wrenches (k, 12) and its Newton corrections into
    iterations (k,). Returns (steps done: k, or the index of the first step that did not converge; the
    contribution's state after them)."""
    prescribed, base_nodes, base_local_r, base_local_rx = base
    states, wrenches, iterations = outputs
    n = history.shape[1]
    scratch = np.empty((10, n))  # the run's one allocation: the step's rows, the accepted ones, Q and the base axis
    values, current, ext_Q, axis = scratch[:4], scratch[4:8], scratch[8], scratch[9, :3]
    current[:, :] = history
    no_band = work[2][:0]  # (0, ...): no matrix
    rows, elements = base_tables(solver[5]), element_work(solver[5])
    forces = acting(state)
    for i in range(times.size):
        motion, rotation = motions[i], rotations[i]
        # 1. predict: the base nodes' prescribed rows (q, q', q'') from the base motion (eqs. 18-19), the base axis
        rigid_node_kinematics(motion[0:3], rotation, motion[7:10], motion[10:13], motion[13:16], motion[16:19],
                              base_local_r, base_local_rx, base_nodes, prescribed)
        axis[:] = rotation[:, 0]
        moved = False
        for j in range(19 if keep_matrix else 0):
            moved = moved or motion[j] != last_motion[j]
            last_motion[j] = motion[j]
        status, total, _ = solve_step(values, current, prescribed, axis, rotation, constant_Q, ext_Q, solver, work,
                                      control, keep_matrix, moved, forces, assemble)  # 2.-3.
        if status != CONVERGED:
            control[FACTORED] = 0
            return i, state
        if total > 1:  # the matrix is kept for the next step only while a single correction sufficed
            control[FACTORED] = 0
        current[:, :] = values  # 4. commit
        states[i] = values
        iterations[i] = total
        q, qd = values[0], values[1]
        state = advance(state, q, qd, times[i])
        forces = acting(state)
        if n == 12 or touches_base(forces):  # 5. reaction
            ext_Q[:] = constant_Q
            assemble(forces, q, qd, rotation, ext_Q, no_band, 0, 0.0, 0.0)
        else:
            ext_Q[:] = held_Q
        base_wrench_kernel(q, qd, values[2], *rows, rotation, ext_Q[:6], elements, wrenches[i])
    return times.size, state


@njit(cache=True)
def general_step(values, current, prescribed, constant_Q, axis, rotation, coef, tol, max_iterations, active, scale,
                 tables, kl, residual, band, pivots, factorization, control):
    """:func:`solve_step` on a fresh matrix under constant forces only: the general path's (sub-)step."""
    return solve_step(values, current, prescribed, axis, rotation, constant_Q, np.empty(constant_Q.size),
                      (coef, tol, max_iterations, active, scale, tables, kl),
                      (residual, band, band[:0], pivots, factorization), control, False, False, 0.0, no_forces)


@njit(cache=True)
def integrate_sequence(history, times, motions, rotations, coef, ext_Q, tol, max_iterations, prescribed, base_nodes,
                       base_local_r, base_local_rx, active, scale, tables, residual, band, pivots, factorization, kl,
                       control, keep_matrix, last_motion, states, wrenches, iterations):
    """:func:`run_steps` without state-dependent contributions (gravity, world-frame point loads): the simulator's
    fixed-rate loop with the matrix kept across steps where it may be (``keep_matrix``), and the general step
    (``Integrator.step``) on a fresh one. Returns the steps done."""
    done, _ = run_steps(history, times, motions, rotations, ext_Q, ext_Q,
                        (coef, tol, max_iterations, active, scale, tables, kl),
                        (prescribed, base_nodes, base_local_r, base_local_rx),
                        (residual, band, np.zeros((0, 0)), pivots, factorization), control, last_motion,
                        keep_matrix, 0.0, itself, no_forces, keep, off_base, (states, wrenches, iterations))
    return done


def interpreted(function, **callees):
    """The source of the compiled ``function`` run by the interpreter, with the named callees replaced (their own
    interpreted versions): the one Newton step for contributions written in Python (``assemble`` a Python
    function)."""
    source = function.py_func
    return types.FunctionType(source.__code__, {**source.__globals__, **callees}, source.__name__,
                              source.__defaults__)


@njit(cache=True)
def keep(state, q, qd, t):
    """The advance kernel of a contribution without state."""
    return state


@njit(cache=True)
def itself(state):
    """The acting kernel of a contribution whose state is what its assemble kernel reads."""
    return state


@njit(cache=True)
def off_base(state):
    """The touches_base kernel of a contribution that never acts on the base element."""
    return False


@njit(cache=True)
def constants_only(state, constants):
    """The load kernel of a contribution without state: its constants are what the step loop carries."""
    return constants


@njit(cache=True)
def nothing(carried):
    """The store kernel of a contribution without state."""
    return np.zeros(0)


def pack(arrays) -> np.ndarray:
    """The packed arrays of composed contributions in one: the sizes of all but the last, then their values (one
    array: itself)."""
    if len(arrays) == 1:
        return np.asarray(arrays[0], dtype=float)
    return np.concatenate([[a.size for a in arrays[:-1]], *arrays]).astype(float, copy=False)


def unpack(packed: np.ndarray, count: int) -> list[np.ndarray]:
    """The ``count`` arrays of :func:`pack` (views)."""
    if count == 1:
        return [packed]
    arrays, start = [], count - 1
    for size in packed[:count - 1].astype(np.int64):
        arrays.append(packed[start:start + size])
        start += size
    return [*arrays, packed[start:]]


class Kernels(NamedTuple):
    """A contribution's compiled kernels (module docstring): ``load(state, constants) -> carried`` from its packed
    state and constants (float64 arrays), ``store(carried) -> state`` packed, then the step loop's four. Each a
    module-level numba function (the composed run imports it by name)."""

    load: object
    store: object
    acting: object
    assemble: object
    advance: object
    touches_base: object


Parts = tuple[Kernels, ...]  # a contribution made of parts: the first a record that the others read
_RUNS: dict[tuple[Parts, ...], object] = {}
_ARGUMENTS = ("history, times, motions, rotations, coef, constant_Q, tol, max_iterations, prescribed, base_nodes, "
              "base_local_r, base_local_rx, active, scale, tables, residual, band, ext_band, pivots, factorization, "
              "kl, control, state, constants, states, wrenches, iterations")


def parts_of(kernels: Kernels | Parts) -> Parts:
    """A contribution's kernels as its parts: one :class:`Kernels`, or parts (the first a shared record whose
    carried state after the step each other part's advance takes as a fifth argument)."""
    return (kernels,) if isinstance(kernels, Kernels) else tuple(kernels)


def compiled_run(kernels: tuple[Kernels | Parts, ...]):
    """The compiled run of steps (:func:`run_steps`, a fresh matrix every step) through the contributions given by
    their kernels (each a :class:`Kernels` or its parts, :func:`parts_of`): a numba function of (history, times,
    motions, rotations, scheme coefficients, constant force, ``Integrator.run_arguments`` after the coefficients,
    control flags, packed state, packed constants, states, wrenches, iterations) returning (steps done, packed state
    after). The packed arrays are :func:`pack`'s of the contributions' (a contribution of parts: :func:`pack`'s of
    its parts').

    Its source composes every part's kernels by name, one level, into a generated module (one file per composition,
    written once under numba's cache directory), so that numba caches it on disk like any module-level function;
    one per process. Forces are added in the general path's order (``integrators.assemble_python``: the constant
    force, then each contribution's sum): into a zero Q the first contribution's parts, then the constant force,
    then each other contribution summed on a zeroed work array, so both paths give the same bits."""
    groups = tuple(parts_of(contribution) for contribution in kernels)
    if groups not in _RUNS:
        _RUNS[groups] = _load_module(_composed_source(groups, True)).run
    return _RUNS[groups]


def compose(kernels: tuple[Kernels, ...], shared: bool = False):
    """The generated module of the contributions given by their kernels, composed into one on :func:`pack`'s
    packed states and constants, for the general path and readouts: ``packed_assemble(state, constants, q, qd,
    rotation, Q, band, kl, c_q, c_qd)`` (each contribution's force added to Q in order), ``packed_advance(state,
    constants, q, qd, t)``, ``packed_touches_base(state, constants)`` and ``packed_parts(state, constants, q, qd,
    rotation)``: each contribution's generalized force alone (count, n). ``shared``: they are the parts of one
    contribution (:func:`parts_of`), the first a record the others read."""
    return _load_module(_composed_source((tuple(kernels),) if shared else tuple((k,) for k in kernels), False))


def _split(array: str, count: int, names: list[str]) -> list[str]:
    """Source lines slicing :func:`pack`'s ``array`` into its ``count`` arrays ``names``."""
    if count == 1:
        return [f"    {names[0]} = {array}"]
    lines = [f"    i = {count - 1}"]
    for k in range(count - 1):
        lines += [f"    {names[k]} = {array}[i:i + int({array}[{k}])]", f"    i += int({array}[{k}])"]
    return [*lines, f"    {names[-1]} = {array}[i:]"]


def _composed_source(groups: tuple[Parts, ...], run: bool) -> str:
    imports, rows = [], "q, qd, rotation, Q, band, kl, c_q, c_qd"
    flat = [kernels for group in groups for kernels in group]
    for k, contribution in enumerate(flat):
        for role, function in zip(Kernels._fields, contribution):
            py_func = function.py_func
            if "<locals>" in py_func.__qualname__:
                raise TypeError(f"kernel {py_func.__qualname__} must be a module-level function")
            imports.append(f"from {py_func.__module__} import {py_func.__name__} as {role}_{k}")
    first = [sum(map(len, groups[:g])) for g in range(len(groups))]  # each group's first part
    members = [list(range(start, start + len(group))) for start, group in zip(first, groups)]
    each = range(len(flat))
    load = _split("state", len(groups), [f"sg{g}" for g in range(len(groups))])
    load += _split("constants", len(groups), [f"cg{g}" for g in range(len(groups))])
    for g, ks in enumerate(members):
        load += _split(f"sg{g}", len(ks), [f"s{k}" for k in ks]) + _split(f"cg{g}", len(ks), [f"c{k}" for k in ks])
    # run: the constant force (and a work array for the contributions after the first) ride along, one level
    extra = (["constant_Q", "own"] if len(groups) > 1 else ["constant_Q"]) if run else []
    ride = "".join(f"carried[{len(flat) + j}], " for j in range(len(extra)))
    load.append("    return (" + "".join(f"load_{k}(s{k}, c{k}), " for k in each) + "".join(f"{e}, " for e in extra)
                + ")")
    store = [f"    x{k} = store_{k}(carried[{k}])" for k in each]  # one buffer in pack's layout, two levels
    store += [f"    n{g} = {len(ks) - 1} + " + " + ".join(f"x{k}.size" for k in ks) for g, ks in enumerate(members)]
    store += [f"    out = np.empty({len(groups) - 1} + " + " + ".join(f"n{g}" for g in range(len(groups))) + ")",
              f"    i = {len(groups) - 1}"]
    store += [f"    out[{g}] = n{g}" for g in range(len(groups) - 1)]
    for ks in members:
        store += [f"    out[i + {j}] = x{k}.size" for j, k in enumerate(ks[:-1])] + [f"    i += {len(ks) - 1}"]
        for k in ks:
            store += [f"    out[i:i + x{k}.size] = x{k}", f"    i += x{k}.size"]
    advance = []
    for ks in members:  # the record first, then each other part from it
        advance.append(f"    a{ks[0]} = advance_{ks[0]}(carried[{ks[0]}], q, qd, t)")
        advance += [f"    a{k} = advance_{k}(carried[{k}], q, qd, t, a{ks[0]})" for k in ks[1:]]
    advance.append("    return (" + "".join(f"a{k}, " for k in each) + ride + ")")

    def added(ks, into: str) -> str:
        return " and ".join(f"assemble_{k}(forces[{k}], q, qd, rotation, {into}, band, kl, c_q, c_qd)" for k in ks)
    bodies = {f"load(state, constants{''.join(', ' + e for e in extra)})": "\n".join(load),
              "store(carried)": "\n".join([*store, "    return out"]),
              "acting(carried)": "    return (" + "".join(f"acting_{k}(carried[{k}]), " for k in each) + ride + ")",
              "advance(carried, q, qd, t)": "\n".join(advance),
              "touches_base(forces)": "    return " + " or ".join(f"touches_base_{k}(forces[{k}])" for k in each)}
    if run:
        assemble = [f"    ok = {added(members[0], 'Q')}", f"    Q += forces[{len(flat)}]"]
        for ks in members[1:]:
            own = f"forces[{len(flat) + 1}]"
            assemble += [f"    {own}[:] = 0.0", f"    ok = ok and {added(ks, own)}", f"    Q += {own}"]
        bodies[f"assemble(forces, {rows})"] = "\n".join([*assemble, "    return ok"])
        own = ", np.empty(constant_Q.size)" if len(groups) > 1 else ""
        entry = f"""@njit(cache=True)
def run({_ARGUMENTS}):
    done, carried = run_steps(history, times, motions, rotations, np.zeros(constant_Q.size), constant_Q,
                              (coef, tol, max_iterations, active, scale, tables, kl),
                              (prescribed, base_nodes, base_local_r, base_local_rx),
                              (residual, band, ext_band, pivots, factorization), control, np.empty(19), False,
                              load(state, constants, constant_Q{own}), acting, assemble, advance, touches_base,
                              (states, wrenches, iterations))
    return done, store(carried)"""
    else:
        parts = ["    out = np.zeros((N, q.size))", "    no_band = np.zeros((0, 0))"]
        parts += [f"    assemble_{k}(forces[{k}], q, qd, rotation, out[{k}], no_band, 0, 0.0, 0.0)" for k in each]
        bodies.update({f"assemble(forces, {rows})": f"    return {added(each, 'Q')}",
                       "_parts(forces, q, qd, rotation)": "\n".join([*parts, "    return out"])})
        entry = f"""@njit(cache=True)
def packed_assemble(state, constants, {rows}):
    return assemble(acting(load(state, constants)), {rows})


@njit(cache=True)
def packed_advance(state, constants, q, qd, t):
    return store(advance(load(state, constants), q, qd, t))


@njit(cache=True)
def packed_touches_base(state, constants):
    return touches_base(acting(load(state, constants)))


@njit(cache=True)
def packed_parts(state, constants, q, qd, rotation):
    return _parts(acting(load(state, constants)), q, qd, rotation)"""
    composed = "\n\n\n".join(f"@njit(cache=True)\ndef {head}:\n{body}" for head, body in bodies.items())
    what = "run" if run else "composition"
    return f'''"""Generated by needle_sim_ros.model.step: the compiled {what} of {len(flat)} part(s)."""
import numpy as np
from numba import njit

from needle_sim_ros.model.step import run_steps
{chr(10).join(imports)}

N = {len(flat)}


{composed}


{entry}
'''


def _load_module(source: str):
    name = "needle_composed_" + hashlib.sha256(source.encode()).hexdigest()[:16]
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, _written(name, source))
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _written(name: str, source: str) -> Path:
    """The composed module's file, written once (numba's cache keys on its time stamp) under numba's cache
    directory, else the user's cache, else the temporary directory (a read-only home)."""
    folders = [Path(numba.config.CACHE_DIR)] if numba.config.CACHE_DIR else []
    folders += [Path.home() / ".cache" / "needle_sim", Path(tempfile.gettempdir()) / f"needle_sim-{os.getuid()}"]
    for folder in (folder / "composed" for folder in folders):
        path = folder / f"{name}.py"
        try:
            if not path.is_file() or path.read_text() != source:
                folder.mkdir(parents=True, exist_ok=True)
                scratch = folder / f".{name}.{os.getpid()}"
                scratch.write_text(source)
                os.replace(scratch, path)
            return path
        except OSError as error:
            failure = error
    raise failure
