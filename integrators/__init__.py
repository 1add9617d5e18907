"""Time integration of COBRA: semi-implicit Euler with the Stribeck ground and Dynamixel actuators."""
from integrators.simulator import (ServoGains, SimSettings, SimState, SimulationDiverged, Simulator,
                                   Trajectory)

__all__ = ["ServoGains", "SimSettings", "SimState", "SimulationDiverged", "Simulator", "Trajectory"]
