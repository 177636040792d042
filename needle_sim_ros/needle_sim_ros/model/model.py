"""The immutable needle model (mesh, mass, quadrature, damping, partition) and the small mutable state."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .damping import DampingTables, damping_tables
from .elastic import ElasticTables, elastic_tables
from .fixtures import Fixture
from .kinematics import BaseMotion
from .mass import mass_slot_matrix
from .mesh import Interpolation, Mesh, clamped_element_lengths
from .partition import Partition
from .properties import NeedleProperties


@dataclass
class State:
    """q, q', q'' (n_dof,) at time t. ``aux``: the generalized-alpha acceleration-like vector a (None: the
    integrator starts from consistent accelerations); ``base``: the base motion at t (optional)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    t: float = 0.0
    aux: np.ndarray | None = None
    base: BaseMotion | None = None


@dataclass(frozen=True, eq=False)
class NeedleModel:
    """Everything constant about the discretized needle (build with ``build_model``): mass_slots, the scalar factor of
    the consistent mass matrix (M = kron(mass_slots, I3), eq. 7); elastic: quadrature tables of eqs. 12-13; damping:
    Rayleigh tables; partition: q_c / q_a (eqs. 18-19); increment_scale: per-coordinate scale of Newton corrections
    (L for positions, 1 for gradients)."""

    props: NeedleProperties
    mesh: Mesh
    axial_gauss: int
    bending_gauss: int
    rayleigh_alpha: float
    rayleigh_beta: float
    fixtures: tuple[Fixture, ...]
    mass_slots: np.ndarray
    elastic: ElasticTables
    damping: DampingTables
    partition: Partition
    increment_scale: np.ndarray

    @property
    def n_elements(self) -> int:
        return self.mesh.n_elements

    @property
    def n_nodes(self) -> int:
        return self.mesh.n_elements + 1

    @property
    def n_dof(self) -> int:
        return 6 * self.n_nodes

    @property
    def mass_matrix(self) -> np.ndarray:
        """Consistent mass matrix M (eqs. 7, 16), dense (n_dof, n_dof)."""
        return np.kron(self.mass_slots, np.eye(3))

    def interpolation(self, arc_lengths) -> Interpolation:
        """Element index and S, S_x, S_xx tables (eq. 4) at reference arc lengths in [0, L]."""
        return self.mesh.interpolation(arc_lengths)

    def straight_state(self, base: BaseMotion, t: float = 0.0, clamp: BaseMotion | None = None) -> State:
        """Undeformed needle along the holder axis, moving rigidly with the base; clamped nodes as prescribed (those
        held where the needle started at ``clamp``, default: here, now)."""
        nodes = np.arange(self.n_nodes)
        local_r = self.mesh.node_arc_length[:, None] * np.array([[1.0, 0.0, 0.0]])
        local_rx = np.tile([1.0, 0.0, 0.0], (self.n_nodes, 1))
        values = np.zeros((3, self.n_dof))
        base.impose_nodes(local_r, local_rx, nodes, values)
        self.partition.impose(base, t, values, clamp)
        q, qd, qdd = values
        return State(q, qd, qdd, float(t), None, base)


def build_model(props: NeedleProperties, n_elements: int = 10, element_lengths=None, axial_gauss: int = 2,
                bending_gauss: int = 3, rayleigh_alpha: float = 0.0, rayleigh_beta: float = 0.0,
                fixtures=()) -> NeedleModel:
    """Discretize the needle into cable elements: the given element lengths [m]; without them n_elements equal
    ones, or where fixtures clamp intervals, :func:`clamped_element_lengths` (nodes at the clamps' ends)."""
    if not isinstance(props, NeedleProperties):
        raise TypeError(f"props must be NeedleProperties, got {type(props).__name__}")
    fixtures = tuple(fixtures)
    intervals = [fixture.interval for fixture in fixtures if fixture.interval is not None]
    if element_lengths is None and intervals and isinstance(n_elements, (int, np.integer)):
        element_lengths = clamped_element_lengths(props.length, int(n_elements), intervals)
    mesh = Mesh.build(props.length, n_elements, element_lengths)
    elastic = elastic_tables(mesh, props, axial_gauss, bending_gauss)
    mass_slots = mass_slot_matrix(mesh, props.mass_per_length)
    partition = Partition.build(mesh, fixtures)
    n_dof = 6 * (mesh.n_elements + 1)
    scale = np.tile(np.r_[np.full(3, props.length), np.ones(3)], n_dof // 6)
    return NeedleModel(props, mesh, int(axial_gauss), int(bending_gauss), float(rayleigh_alpha),
                       float(rayleigh_beta), fixtures, mass_slots, elastic,
                       damping_tables(mass_slots, elastic, rayleigh_alpha, rayleigh_beta), partition, scale)
