"""Contacts between the hand and an object: friction pyramids, the contact-force QP
(dissertation eq. III.23 / seed 000 eq. 10-11) and the dynamic feasibility LP (III.10-III.16)."""

from hand_control.contact.feasibility import FeasibilityResult, dynamic_feasibility
from hand_control.contact.friction import contact_frames, pyramid_edges
from hand_control.contact.qp import (
    ContactForceQP,
    ContactForceResult,
    ContactQPConfig,
    ReferenceContactQP,
)
from hand_control.contact.types import ContactSet

__all__ = [
    "ContactForceQP",
    "ContactForceResult",
    "ContactQPConfig",
    "ContactSet",
    "FeasibilityResult",
    "ReferenceContactQP",
    "contact_frames",
    "dynamic_feasibility",
    "pyramid_edges",
]
