"""Option handling: every option value or option call that cannot mean anything is refused with a clear
error that names the option (or the keyword and the callable), before any work; valid options build as before.
"""
import numpy as np
import pytest

import warp_subdiv as ws
from warp_subdiv import Options, SubdivInputError

# two quads sharing edge (1, 4):  0 1 2 / 3 4 5
GRID_PTS = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], dtype=np.float64)
GRID_COUNTS = [4, 4]
GRID_IDX = [0, 1, 4, 3, 1, 2, 5, 4]


def grid(**tags):
    return ws.Mesh(GRID_PTS, GRID_COUNTS, GRID_IDX, **tags)


# --------------------------------------------------------------------------------------------------------
# options that only the paper's rules have

@pytest.mark.parametrize("strength", [0.5, 0.0, np.float32(0.25)])
def test_normal_strength_refused_under_opensubdiv_rules(strength):
    """OpenSubdiv has no normal control: a normal_strength other than the default under rules='opensubdiv'
    would be silently ignored, so it is refused like flatness, naming normal_strength."""
    with pytest.raises(SubdivInputError, match="normal_strength.*opensubdiv") as info:
        Options(rules="opensubdiv", normal_strength=strength)
    assert (info.value.option, info.value.value) == ("normal_strength", float(strength))
    with pytest.raises(SubdivInputError) as info:
        ws.Refiner(grid(), 1, device="cpu", rules="OpenSubdiv", normal_strength=strength)
    assert info.value.option == "normal_strength"
    with pytest.raises(SubdivInputError):
        Options(normal_strength=strength).replace(rules="opensubdiv")


@pytest.mark.parametrize("strength", [1.0, 1, np.float64(1.0)])
def test_default_normal_strength_accepted_under_opensubdiv_rules(strength):
    """The default strength (1) asks for nothing: it stays accepted with rules='opensubdiv'."""
    assert Options(rules="opensubdiv", normal_strength=strength) == Options(rules="opensubdiv")
    ws.Refiner(grid(), 1, device="cpu", rules="opensubdiv", normal_strength=strength)
