"""Sub-diagrams for the thesis's multi-system blocks.

Every ``Add*`` helper of the library adds one system to the caller's builder
and returns it: a LeafSystem where one system is the whole block, otherwise
a sub-diagram (the force sensor and its noise, the DSP's channels, the
kinematic estimator, the encoders, the joint friction, the identifiers)
whose ports are exported by name, so a block is wired and tested like any
other system: ``block.GetInputPort("wrench")``, ``block.GetOutputPort("voltage")``.
"""

from pydrake.systems.framework import Diagram, DiagramBuilder, InputPort, PortDataType
from pydrake.systems.primitives import Demultiplexer, Multiplexer

from drake_contact.errors import ScenarioError


def AddSubdiagram(builder: DiagramBuilder, name: str, build):
    """Adds the sub-diagram ``name`` made by ``build(inner_builder)``.

    ``build`` adds the block's systems to the inner builder and returns a
    mapping {port name: port} of the inner ports to export, inputs and
    outputs alike (an input port listed under one name may be given as a
    list of inner input ports, all fed by the exported input). Returns the
    sub-diagram, added to ``builder``.
    """
    return builder.AddSystem(_subdiagram(name, build))


def system_ports(system) -> dict:
    """Every input port and every vector output port of ``system`` by name
    (the ports dict of :func:`AddSubdiagram` and :func:`AddEnvironments`)."""
    inputs = {system.get_input_port(i).get_name(): system.get_input_port(i)
              for i in range(system.num_input_ports())}
    return inputs | {system.get_output_port(i).get_name(): system.get_output_port(i)
                     for i in range(system.num_output_ports())
                     if system.get_output_port(i).get_data_type() == PortDataType.kVectorValued}


class EnvironmentCopies(Diagram):
    """N one-environment blocks as one system with environment-major ports:
    each input split by a Demultiplexer (``<port>_split``), each output
    joined by a Multiplexer (``<port>_join``); environment i's block is the
    sub-diagram ``<name>_<i>``, kept in ``environments[i]`` (the explicit
    map from each system to its environment: :func:`drake_contact.diagram.SeedNoise`
    seeds the noise inside it with environment i's seed).

    ``build(builder, i)`` adds environment i's systems to ``builder`` and
    returns its ports as :func:`AddSubdiagram`'s ``build`` does; every
    environment's block must have the same ports at the same sizes. For a
    role that is not batched (a plug-in without ``ensemble``, the safety
    supervisor, the contact detector, the faults)."""

    def __init__(self, name: str, count: int, build):
        super().__init__()
        builder = DiagramBuilder()
        self.environments = [builder.AddSystem(_subdiagram(f"{name}_{i}", lambda inner, i=i:
                                                           build(inner, i)))
                             for i in range(count)]
        first = self.environments[0]
        for p in range(first.num_input_ports()):
            port = first.get_input_port(p)
            split = builder.AddNamedSystem(f"{port.get_name()}_split",
                                           Demultiplexer([port.size()] * count))
            for i, block in enumerate(self.environments):
                builder.Connect(split.get_output_port(i), block.get_input_port(p))
            builder.ExportInput(split.get_input_port(), port.get_name())
        for p in range(first.num_output_ports()):
            port = first.get_output_port(p)
            join = builder.AddNamedSystem(f"{port.get_name()}_join",
                                          Multiplexer([port.size()] * count))
            for i, block in enumerate(self.environments):
                builder.Connect(block.get_output_port(p), join.get_input_port(i))
            builder.ExportOutput(join.get_output_port(), port.get_name())
        builder.BuildInto(self)
        self.set_name(name)


def AddEnvironments(builder: DiagramBuilder, name: str, count: int, build) -> dict:
    """The one adapter for a role that is not batched: ``build(builder, i)``
    adds environment i's systems and returns its ports by name (inputs as a
    port or a list of ports fed together, as :func:`AddSubdiagram`). One
    environment: its systems go straight into ``builder`` and the ports are
    returned as they are (a batch of one is the system alone). N > 1: an
    :class:`EnvironmentCopies` ``name`` of the N blocks is added, and its
    environment-major ports are returned by name."""
    if count == 1:
        return build(builder, 0)
    return system_ports(builder.AddSystem(EnvironmentCopies(name, count, build)))


def connect(builder: DiagramBuilder, source, destination):
    """Connects the output port ``source`` to the input ``destination``, or
    to each of a list of inputs fed together (a ports dict's input)."""
    for port in destination if isinstance(destination, (list, tuple)) else [destination]:
        builder.Connect(source, port)


def _subdiagram(name, build):
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
    return diagram


def environment_configs(config, kind, prefix) -> list:
    """A system's configs, one per environment it serves: ``[config]`` for
    one ``kind`` instance, the list for a sequence of them (ScenarioError
    naming ``prefix`` when it is empty)."""
    if isinstance(config, kind):
        return [config]
    configs = list(config)
    if not configs:
        raise ScenarioError(f"{prefix}: no configs (one per environment, at least one)")
    return configs


class Layout:
    """The named fields of a flat vector, in order (a law's output and held
    state): ``Layout(("tau", 3), ("mode", 1))``. ``layout.tau`` is the
    field's slice, ``layout.mode`` the index of a field of size 1;
    ``layout.size`` is the vector's size, ``layout.sizes`` the fields'
    sizes in order (a Demultiplexer's), and ``layout.span(first, last)``
    the slice from one field through another. The offsets are summed here,
    once, from the sizes."""

    def __init__(self, *fields):
        self._fields = {}
        offset = 0
        for name, size in fields:
            if (name in self._fields or not name.isidentifier() or name.startswith("_")
                    or hasattr(Layout, name) or name in ("size", "sizes") or size < 1):
                raise ValueError(f"Layout field {name!r} of size {size}: names must be "
                                 "unique identifiers, not _private nor the layout's own "
                                 "(size, sizes, span, names), and sizes at least 1")
            self._fields[name] = (offset, size)
            setattr(self, name, offset if size == 1 else slice(offset, offset + size))
            offset += size
        self.size = offset
        self.sizes = [size for _, size in self._fields.values()]

    def span(self, first, last):
        """The slice from field ``first`` through field ``last``."""
        start, _ = self._fields[first]
        end, size = self._fields[last]
        return slice(start, end + size)

    def names(self):
        return list(self._fields)
