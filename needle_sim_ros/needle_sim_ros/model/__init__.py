"""ROS-free 3D ANCF needle model of seed 000 (Sec. II, eqs. 1-20): gradient-deficient cable elements, consistent
mass, exact-curvature elastic forces with analytic Jacobian, Rayleigh damping, general external forces, a rigid
base driving the constrained coordinates, fixtures, implicit integrators, statics and the base reaction wrench."""
from .config import load_needle_config, needle_parameters, needle_properties
from .data import NeedleData, acting_forces, initial_force_states, stateful_forces, step
from .elastic import elastic_energy, elastic_forces, tangent_stiffness
from .fixtures import Fixture
from .forces import (ElementLocalForce, ForceContribution, GeneralizedForce, Gravity, LineLoad, MaterialPointForce,
                     NodalLoad, PointForces, PointLoad, check_forces)
from .integrators import Integrator, StepFailed, StepResult
from .kinematics import BaseMotion
from .mesh import Interpolation
from .model import NeedleModel, State, build_model
from .outputs import (Centerline, ModelShape, axial_strain, centerline, curvature, gravitational_energy,
                      kinetic_energy, model_shape, tip_pose)
from .properties import NeedleProperties
from .reaction import BaseWrench, reaction_wrench
from .statics import StaticResult, StaticSolveFailed, solve_static

__all__ = ["NeedleProperties", "build_model", "NeedleModel", "State", "Interpolation", "BaseMotion", "Fixture",
           "ForceContribution", "ElementLocalForce", "check_forces", "GeneralizedForce", "Gravity", "PointLoad",
           "NodalLoad", "LineLoad", "MaterialPointForce", "PointForces", "Integrator", "StepResult", "StepFailed",
           "solve_static", "StaticResult", "StaticSolveFailed", "reaction_wrench", "BaseWrench", "centerline",
           "Centerline", "tip_pose", "ModelShape", "model_shape", "axial_strain", "curvature", "kinetic_energy",
           "elastic_energy", "gravitational_energy", "elastic_forces", "tangent_stiffness", "load_needle_config",
           "needle_parameters", "needle_properties", "NeedleData", "acting_forces", "initial_force_states",
           "stateful_forces", "step"]
