"""implicit_contact: the geometrically implicit contact stepper of [GI] for DART worlds.

Chakraborty, Berard, Akella & Trinkle, "A geometrically implicit time-stepping method for
multibody systems with intermittent contact", IJRR 2013.

    import implicit_contact as ic
    ic.attach(body_node, ic.shapes.Sphere(0.5), friction=ic.Friction(mu=0.4))
    stepper = ic.ImplicitContactStepper(world)
    report = stepper.step()
"""
from . import shapes
from .params import Compliance, Friction
from .dart_adapter import attach, urdf_mimic_joints
from .stepper import ImplicitContactStepper, StepperOptions, StepReport, ContactReport, StepFailure

__all__ = ["shapes", "Compliance", "Friction", "attach", "urdf_mimic_joints", "ImplicitContactStepper", "StepperOptions", "StepReport",
           "ContactReport", "StepFailure"]
