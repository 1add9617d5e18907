"""COBRA's model: the URDF in Pinocchio, the partitioned dynamics, parameters, gait and runs."""
from cobra_model.errors import InputError
from cobra_model.gait import SidewindingGait
from cobra_model.model import CobraModel, RobotModel
from cobra_model.parameters import ModelParameters, Parameter

__all__ = ["CobraModel", "InputError", "ModelParameters", "Parameter", "RobotModel", "SidewindingGait"]
