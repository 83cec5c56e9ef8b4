"""The named layout of the laws' wide vectors (drake_contact.blocks.Layout)."""

import numpy as np
import pytest

from drake_contact.blocks import Layout
from drake_contact.control import baselines, force_monitor, hybrid_controller, safety_supervisor


def test_layout_offsets_follow_the_sizes():
    layout = Layout(("tau", 3), ("mode", 1), ("info", 4), ("rest", 2))
    assert layout.tau == slice(0, 3)
    assert layout.mode == 3
    assert layout.info == slice(4, 8)
    assert layout.rest == slice(8, 10)
    assert layout.size == 10 and layout.sizes == [3, 1, 4, 2]
    assert layout.span("mode", "info") == slice(3, 8)
    assert layout.names() == ["tau", "mode", "info", "rest"]
    v = np.arange(layout.size)
    assert v[layout.info].tolist() == [4, 5, 6, 7] and v[layout.mode] == 3


@pytest.mark.parametrize("fields", [(("a", 1), ("a", 2)), (("a", 0),), (("not a name", 1),),
                                    (("size", 1),), (("span", 2),), (("_fields", 1),)])
def test_layout_refuses_bad_fields(fields):
    with pytest.raises(ValueError, match="Layout field"):
        Layout(*fields)


def test_the_laws_layouts_tile_their_vectors():
    # Every element belongs to exactly one field, and the sizes the ports
    # and Demultiplexers use are the layouts'.
    for layout in (hybrid_controller._LAW, safety_supervisor._LAW, baselines._LAW,
                   force_monitor._STATE):
        covered = np.zeros(layout.size, dtype=int)
        for name in layout.names():
            covered[getattr(layout, name)] += 1
        assert covered.tolist() == [1] * layout.size
    assert hybrid_controller._LAW.size == 27
    assert safety_supervisor._LAW.size == 20
    assert baselines._LAW.size == 10
    assert force_monitor._STATE.size == 6
