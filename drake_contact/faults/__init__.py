"""Injected faults (:mod:`.base`: the scenario's ``faults:`` list, the
systems that corrupt a signal, the contact clock; :mod:`.builtin`: the
built-in kinds). A new kind is a :class:`FaultKind` subclass with
:func:`register_fault_kind` on it."""

from importlib.metadata import entry_points

import drake_contact.faults.builtin  # noqa: F401 - registers the built-in kinds
from drake_contact.faults.base import (
    CONTACT_CLOCK_FORCE_N, FAULT_KIND_GROUP, FAULT_KINDS, NULL_CASE, SIGNALS, START_FROM,
    AddFault, AddFaultChain, ChainFaults, FaultClock, FaultConfig, FaultKind, FaultLaw, StudyCase,
    register_fault_kind, unregister_fault_kind, validate_faults)

# Other packages' kinds: importing each module named in the group registers them.
for _entry in entry_points(group=FAULT_KIND_GROUP):
    _entry.load()

__all__ = [
    "CONTACT_CLOCK_FORCE_N", "FAULT_KIND_GROUP", "FAULT_KINDS", "NULL_CASE", "SIGNALS", "START_FROM", "AddFault", "AddFaultChain",
    "ChainFaults",
    "FaultClock", "FaultConfig", "FaultKind", "FaultLaw", "StudyCase", "register_fault_kind",
    "unregister_fault_kind", "validate_faults"]
