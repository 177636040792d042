"""Tissue configuration (ROS 2 params under ``tissue.``) -> the TissueModel.

``TISSUE_PARAMETERS`` declares every key (SI units); ``config/tissue.yaml`` sets them. Per-layer parameters are
parallel arrays under ``tissue.layers.`` (one entry per layer, entry surface first).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needle_common.parameters import ParamSpec, flatten_tree, parameter_tree, unknown_name_error

from .bevel_tip import BevelTip
from .coupling import ShaftSupport, TissueContact
from .geometry import LAYER_PARAMETERS, TissueBlock, TissueLayer
from .insertion_profile import InsertionForceProfile
from .lugre import PARAMETER_NAMES, LuGreParameters, ModifiedLuGre
from .shaft_laws import KARNOPP, LUGRE, PROFILE, ShaftLaw
from .tissue_model import TissueModel

AXIAL_MODELS = ("karnopp", "insertion_profile", "lugre", "none")


def _tissue(name: str, default: object, description: str, **options) -> ParamSpec:
    """A ``tissue.`` parameter; +-inf allowed (e.g. an infinite last layer)."""
    return ParamSpec(f"tissue.{name}", default, description, allow_infinite=True, **options)


TISSUE_PARAMETERS: tuple[ParamSpec, ...] = (
    _tissue("enable", False, "Couple the tissue models to the needle."),
    _tissue("entry_point", [0.28, 0.0, 0.0], "A point of the entry surface, world frame [m].", length=3),
    _tissue("entry_normal", [1.0, 0.0, 0.0], "Entry surface normal pointing into the tissue, world frame.", length=3),
    *(_tissue(f"layers.{name}", [value], meaning[:1].upper() + meaning[1:] + ".") for (name, meaning), value in zip(
        LAYER_PARAMETERS.items(), (np.inf, 2.0e4, 5.0, 6.0, 120.0, 9.42e3))),
    _tissue("shaft.point_spacing", 2.0e-3, "Spacing of the shaft points carrying the distributed forces [m]."),
    _tissue("shaft.lateral_support", True, "Winkler springs/dampers anchoring the shaft to its track."),
    _tissue("shaft.axial_model", "karnopp", "Axial law along the shaft.", choices=AXIAL_MODELS),
    _tissue("shaft.stick_stiffness", 2.0e4, "Axial stiffness of the stick anchors per unit length k_a [N/m^2]; "
            "stick band = C_n / k_a."),
    _tissue("track.spacing", 1.0e-4, "The tip extends its track (path memory: to where it is) after advancing this "
            "far into uncut tissue [m]."),
    _tissue("bevel_tip.enable", True, "Bevel-tip forces P, Q (seed 001 eqs. 4-5) at the tip."),
    _tissue("bevel_tip.bevel_angle", np.deg2rad(30.0), "Bevel angle lambda [rad] (seed 001: 30 deg)."),
    _tissue("bevel_tip.acting_fraction", 0.2, "Beta / lambda, acting-point angle fraction (seed 001: 0.2)."),
    _tissue("bevel_tip.diameter", 0.0, "Needle diameter for the bevel edges a, b [m]; 0 = twice the needle radius."),
    _tissue("bevel_tip.side", [0.0, 1.0, 0.0], "Bevel side (where Q pushes the tip) in the base frame.", length=3),
    _tissue("insertion_profile.enable", False, "Seed 002 at the tip: capsule stiffness until puncture, then cutting."),
    _tissue("insertion_profile.a1", 1.9, "Capsule stiffness a1 [N/m] (seed 002: 0.0019 N/mm)."),
    _tissue("insertion_profile.a2", 4.99e4, "Capsule stiffness a2 [N/m^2] (seed 002: 0.0499 N/mm^2)."),
    _tissue("insertion_profile.puncture_depth", 3e-3, "Capsule puncture depth d1 [m]; F_s(d1) must stay below the "
            "needle's buckling load."),
    _tissue("insertion_profile.frequencies", [0.0], "Friction series wavenumbers w_1..w_M [rad/m] (0 entries are "
            "dropped)."),
    _tissue("insertion_profile.cos_coefficients", [0.5, 0.0], "Friction series A_0..A_M [N]."),
    _tissue("insertion_profile.sin_coefficients", [0.0], "Friction series B_1..B_M [N]."),
    _tissue("insertion_profile.cutting_force", 0.3, "Cutting force F_c while the tip cuts [N]."),
    _tissue("insertion_profile.cutting_speed_scale", 1.0e-3, "Tip speed over which F_c ramps in [m/s]."),
    _tissue("lugre.f1", 8.0, "Seed 003 f1 [N/m]."),
    _tissue("lugre.f2", 500.0, "Seed 003 f2 [N/m]."),
    _tissue("lugre.sigma0", 2.5e5, "Seed 003 sigma0 [N/m^2]."),
    _tissue("lugre.sigma1", 50.0, "Seed 003 sigma1 [N/m]."),
    _tissue("lugre.sigma2", 12.0, "Seed 003 sigma2 [N/m]."),
    _tissue("lugre.alpha", 125.0, "Seed 003 alpha [1/m]."),
    _tissue("lugre.velocity_scale", 1.0e-4, "Sgn(l') regularisation tanh(l'/v_s) [m/s]."),
)
SPECS = {spec.name: spec for spec in TISSUE_PARAMETERS}


def flatten_tissue_config(config) -> dict:
    """The dotted ``tissue.*`` values, validated by their declarations, of a flat dict, a nested dict, a ROS 2
    params-file dict or a YAML path; ParameterError (a ValueError) naming a bad or unknown one."""
    flat = flatten_tree(parameter_tree(config))  # params file: the merged ros__parameters of its sections
    tissue = {name: value for name, value in flat.items() if name.startswith("tissue.")}
    for name in tissue:
        if name not in SPECS:
            raise unknown_name_error(name, SPECS)
    return {name: SPECS[name].validate(value) for name, value in tissue.items()}


@dataclass(frozen=True)
class TissueConfig:
    """Validated ``tissue.*`` parameters (defaults from TISSUE_PARAMETERS)."""

    values: dict

    @classmethod
    def from_any(cls, config) -> "TissueConfig":
        return cls({**{name: spec.default for name, spec in SPECS.items()}, **flatten_tissue_config(config)})

    def __getitem__(self, key: str):
        return self.values[key]

    def vector(self, key: str) -> np.ndarray:
        return np.asarray(self.values[key], dtype=float)

    def block(self) -> TissueBlock:
        columns = {name: self.vector(f"tissue.layers.{name}") for name in LAYER_PARAMETERS}
        n = columns["thickness"].size
        for name, column in columns.items():
            if column.size != n:
                raise ValueError(f"tissue.layers.{name} has {column.size} entries, tissue.layers.thickness has {n}")
        layers = tuple(TissueLayer(**{name: float(columns[name][i]) for name in LAYER_PARAMETERS}) for i in range(n))
        return TissueBlock(self.vector("tissue.entry_point"), self.vector("tissue.entry_normal"), layers)

    def profile(self) -> InsertionForceProfile:
        p = "tissue.insertion_profile."
        frequencies = self.vector(p + "frequencies")
        keep = frequencies != 0.0
        cos_coefficients = self.vector(p + "cos_coefficients")
        sin_coefficients = self.vector(p + "sin_coefficients")
        if cos_coefficients.size != frequencies.size + 1 or sin_coefficients.size != frequencies.size:
            raise ValueError(f"{p}cos_coefficients needs len(frequencies)+1 entries and {p}sin_coefficients "
                             "len(frequencies) entries")
        return InsertionForceProfile(
            float(self[p + "a1"]), float(self[p + "a2"]), float(self[p + "puncture_depth"]),
            tuple(frequencies[keep]), (cos_coefficients[0], *cos_coefficients[1:][keep]),
            tuple(sin_coefficients[keep]), float(self[p + "cutting_force"]))

    def lugre_parameters(self) -> np.ndarray:
        """Seed 003's six parameters and v_s (checked by ``ModifiedLuGre``) as ``shaft_laws.LUGRE`` reads them."""
        lugre = ModifiedLuGre(LuGreParameters(*(float(self[f"tissue.lugre.{n}"]) for n in PARAMETER_NAMES)),
                              float(self["tissue.lugre.velocity_scale"]))
        return np.append(lugre.parameters.as_array(), lugre.velocity_scale)


def shaft_points(length: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Equally spaced points from the base to the tip (at most ``spacing`` apart) and their trapezoidal-rule
    weights [m]; the tip is a support point, so the tissue holds it laterally from first contact."""
    if not spacing > 0.0:
        raise ValueError(f"tissue.shaft.point_spacing must be > 0, got {spacing!r}")
    n = max(int(np.ceil(length / spacing)), 1)
    weights = np.full(n + 1, length / n)
    weights[[0, -1]] *= 0.5
    return np.linspace(0.0, length, n + 1), weights


def build_tissue_model(config, model) -> TissueModel:
    """The tissue model of the enabled tissue laws (see TISSUE_PARAMETERS) on the needle ``model``."""
    cfg = TissueConfig.from_any(config)
    block = cfg.block()
    axial_model = cfg["tissue.shaft.axial_model"]
    profile_enabled = bool(cfg["tissue.insertion_profile.enable"])
    profile = cfg.profile() if profile_enabled or axial_model == "insertion_profile" else None
    contact = TissueContact(block, float(cfg["tissue.track.spacing"]),
                            profile.puncture_depth if profile_enabled else None)
    stick_stiffness = float(cfg["tissue.shaft.stick_stiffness"])
    if axial_model in ("karnopp", "insertion_profile") and not stick_stiffness > 0.0:  # LuGre: the bristle sticks
        raise ValueError(f"tissue.shaft.stick_stiffness must be > 0, got {stick_stiffness!r}")
    axial_law = {"karnopp": lambda: ShaftLaw(KARNOPP, np.zeros(0), stick_stiffness),
                 "insertion_profile": lambda: ShaftLaw(PROFILE, profile.series_parameters, stick_stiffness),
                 "lugre": lambda: ShaftLaw(LUGRE, cfg.lugre_parameters()),
                 "none": lambda: None}[axial_model]()
    arc_lengths, weights = shaft_points(float(model.props.length), float(cfg["tissue.shaft.point_spacing"]))
    shaft = ShaftSupport(model, block, arc_lengths, weights, bool(cfg["tissue.shaft.lateral_support"]), axial_law)
    bevel = None
    if cfg["tissue.bevel_tip.enable"]:
        diameter = float(cfg["tissue.bevel_tip.diameter"]) or 2.0 * float(model.props.radius)
        bevel = (BevelTip.for_diameter(1.0, float(cfg["tissue.bevel_tip.bevel_angle"]),
                                       float(cfg["tissue.bevel_tip.acting_fraction"]), diameter),
                 cfg.vector("tissue.bevel_tip.side"))
    tip_resistance = ((profile, float(cfg["tissue.insertion_profile.cutting_speed_scale"])) if profile_enabled
                      else None)
    return TissueModel(contact, shaft, bevel, tip_resistance)
