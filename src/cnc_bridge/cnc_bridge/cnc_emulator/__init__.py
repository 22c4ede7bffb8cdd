"""CNC emulator (package): an asyncua OPC UA server with axis positions and temperature-compensation nodes.

``thermal-comp cnc-emulator`` runs it from the command line; :class:`CncEmulator` (async) and
:class:`CncEmulatorThread` (own thread and event loop, start/stop/restart from synchronous
code) use it as a library, e.g. in tests and the demo.

Address space (namespace ``urn:thermal-comp:cnc-emulator``, registered first, so its index
is 2 and the ids below are ``ns=2;s=...``; ``<A>`` is an axis name such as ``X`` or, on a
lathe, ``GB_X``/``T01_X``). The compensation nodes are modelled on SINUMERIK's temperature
compensation:

==================================  ========  ======  ===================================================
node id                             type      access  meaning
==================================  ========  ======  ===================================================
``ns=2;s=Axis.<A>.Position``        Double    read    axis position, mm (linear) or deg (rotary)
``ns=2;s=TempComp.<A>.SD43900``     Double    write   offset, mm (``$SA_TEMP_COMP_ABS_VALUE``)
``ns=2;s=TempComp.<A>.SD43910``     Double    write   slope, mm/mm (``$SA_TEMP_COMP_SLOPE``)
``ns=2;s=TempComp.<A>.SD43920``     Double    write   reference position, mm (``$SA_TEMP_COMP_REF_POSITION``)
``ns=2;s=TempComp.<A>.MD32750``     Int32     write   compensation type/enable, 0 = off (``$MA_TEMP_COMP_TYPE``)
``ns=2;s=TempComp.<A>.Applied``     Double    read    compensation the CNC applies now, mm:
                                                      ``SD43900 + SD43910 * (pos - SD43920)`` if
                                                      MD32750 != 0, else 0
``ns=2;s=Probe.ProbeMove``          Method    call    optional probing interface, see below
==================================  ========  ======  ===================================================

Probing (present only when a ``probe_move`` callable is given): the method
``ProbeMove(artefact: UInt32, c_axis_deg: Double, b_axis_deg: Double, start_mm: Double[3],
direction: Double[3], max_travel_mm: Double) -> (triggered: Boolean, position_mm: Double[3])``
on object ``ns=2;s=Probe`` runs one G31-like skip move: the CNC first turns C and B to the
given angles (the ``Axis.C/B.Position`` nodes follow), then moves from ``start_mm`` along
``direction``; the answer is the axis position read at the skip (or the end of the move if
nothing triggered). The arguments follow thermal_comp_msgs/TouchProbe.srv (artefact 0 =
sphere, 1 = guide bush). The answer comes from the Python callable
``probe_move(ProbeRequest) -> (bool, position_mm[3])``; :func:`artefact_probe` builds one
from ``thermal_twin.machine.artefact_geometry`` and a provider of the true errors, with the
compensation the emulator currently applies.

Modules, one concept each: :mod:`.nodes` (ids, accepted values), :mod:`.access` (sessions,
login back-off), :mod:`.probe` (ProbeMove), :mod:`.server` (the asyncua server),
:mod:`.thread` (synchronous driver), :mod:`.cli` (the command); the names below load on first
use. Security and value checks: docs/security.md and docs/cnc_bridge.md.
"""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "axes": ["DEFAULT_COMPENSATION_AXES", "DEFAULT_POSITION_AXES"],
    "nodes": ["COMPENSATION_NODES", "ENDPOINT_PATH", "NAMESPACE_URI", "PROBE_METHOD_ID", "PROBE_OBJECT_ID",
              "UM_PER_MM", "compensation_node_id", "free_tcp_port", "position_node_id"],
    "probe": ["ProbeMove", "ProbeRequest", "artefact_probe"],
    "server": ["CncEmulator", "EmulatorConfig", "EmulatorState"],
    "thread": ["CncEmulatorThread"],
    "cli": ["main"],      # the entry point thermal-comp cnc-emulator
})
