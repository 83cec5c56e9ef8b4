"""Sub-diagrams for the thesis's multi-system blocks.

Every ``Add*`` helper of the library adds one system to the caller's builder
and returns it: a LeafSystem where one system is the whole block, otherwise
a sub-diagram (the force sensor and its noise, the DSP's channels, the
kinematic estimator, the encoders, the joint friction, the identifiers)
whose ports are exported by name, so a block is wired and tested like any
other system: ``block.GetInputPort("wrench")``, ``block.GetOutputPort("voltage")``.
"""

from pydrake.systems.framework import DiagramBuilder, InputPort


def AddSubdiagram(builder: DiagramBuilder, name: str, build):
    """Adds the sub-diagram ``name`` made by ``build(inner_builder)``.

    ``build`` adds the block's systems to the inner builder and returns a
    mapping {port name: port} of the inner ports to export, inputs and
    outputs alike (an input port listed under one name may be given as a
    list of inner input ports, all fed by the exported input). Returns the
    sub-diagram, added to ``builder``.
    """
    inner = DiagramBuilder()
    for port_name, port in build(inner).items():
        ports = port if isinstance(port, (list, tuple)) else [port]
        if isinstance(ports[0], InputPort):
            exported = inner.ExportInput(ports[0], port_name)
            for other in ports[1:]:
                inner.ConnectInput(exported, other)
        else:
            inner.ExportOutput(port, port_name)
    diagram = inner.Build()
    diagram.set_name(name)
    return builder.AddSystem(diagram)
