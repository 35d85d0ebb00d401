"""Cloth force terms with analytic gradients and Hessians (ARCSim 0.3.1 conventions).

Pure functions of tensors, called every step by the integrator:

* `membrane_forces`: Green-strain membrane energy with Wang 2011 stiffness (per face).
* `bending_forces`: signed dihedral-angle bending (per interior edge / hinge).
* `wind_forces`: ARCSim's face air-drag model and its velocity Jacobian.
* `rest_state`, `build_hinges`, `hinge_rest_data`: once-per-mesh precomputation.
"""

from tryon.sim.forces.bending import bending_energy, bending_forces, dihedral_angle
from tryon.sim.forces.bending import hinge_rest_data
from tryon.sim.forces.geometry import build_hinges, rest_state
from tryon.sim.forces.membrane import membrane_energy, membrane_forces, membrane_strain, psd_stiffness
from tryon.sim.forces.wind import wind_forces

__all__ = [
    "bending_energy",
    "bending_forces",
    "build_hinges",
    "dihedral_angle",
    "hinge_rest_data",
    "membrane_energy",
    "membrane_forces",
    "membrane_strain",
    "psd_stiffness",
    "rest_state",
    "wind_forces",
]
