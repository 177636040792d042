"""Needle-tissue interaction models (ROS-free): seed 001 (Karnopp friction, bevel tip, angular-spring needle),
seed 002 (insertion force profile), seed 003 (modified LuGre + EKF identification), and their coupling to the
ANCF needle as force contributions.

The pure laws and estimators import without the ANCF model; ``build_tissue_forces`` and ``tissue_readout`` (which
need ``needle_sim_ros.model``) are imported on first use.
"""
from .angular_spring import AngularSpringNeedle, identify_bending_stiffness
from .bevel_tip import BevelTip
from .geometry import TissueBlock, TissueLayer, inserted_interval
from .insertion_profile import InsertionForceProfile, fit_insertion_profile
from .karnopp import KarnoppFriction
from .lugre import LuGreParameters, ModifiedLuGre
from .lugre_estimation import TABLE_I_GROUPS, LuGreEstimate, LuGreEstimator, fisher_information, identify_record

_COUPLING_NAMES = ("build_tissue_forces", "tissue_readout", "TissueReadout", "TISSUE_PARAMETERS")


def __getattr__(name: str):
    if name in _COUPLING_NAMES:
        from . import factory
        return getattr(factory, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["AngularSpringNeedle", "identify_bending_stiffness", "BevelTip", "TissueBlock", "TissueLayer",
           "inserted_interval", "InsertionForceProfile", "fit_insertion_profile", "KarnoppFriction",
           "LuGreParameters", "ModifiedLuGre", "TABLE_I_GROUPS", "LuGreEstimate", "LuGreEstimator",
           "fisher_information", "identify_record", *_COUPLING_NAMES]
