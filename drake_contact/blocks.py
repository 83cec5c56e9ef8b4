"""Sub-diagrams for the thesis's multi-system blocks.

Every ``Add*`` helper of the library adds one system to the caller's builder
and returns it: a LeafSystem where one system is the whole block, otherwise
a sub-diagram (the force sensor and its noise, the DSP's channels, the
kinematic estimator, the encoders, the joint friction, the identifiers)
whose ports are exported by name, so a block is wired and tested like any
other system: ``block.GetInputPort("wrench")``, ``block.GetOutputPort("voltage")``.
"""

from pydrake.systems.framework import DiagramBuilder, InputPort

from drake_contact.errors import ScenarioError


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
