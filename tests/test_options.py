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


# --------------------------------------------------------------------------------------------------------
# numeric options are numbers, not bools or strings (which numpy would quietly turn into 1.0 or parse)

NOT_NUMBERS = [True, False, np.bool_(True), "0.5", np.str_("0.5"), b"0.5"]


@pytest.mark.parametrize("value", NOT_NUMBERS + [[0.5, True], [True, False], np.array([True, False]), ["0.5", "0.1"],
                                                 np.array(["0.5"]), np.array(True), [0.5, "0.1"]],
                         ids=repr)
def test_flatness_refuses_bools_and_strings(value):
    """A bool or a string is not a flatness, alone or inside a per-vertex array: SubdivInputError names
    flatness and shows the value."""
    with pytest.raises(SubdivInputError, match=r"flatness must (be|hold) .*got .*(True|False|0\.5|0\.1)") as info:
        Options(flatness=value)
    assert info.value.option == "flatness"
    with pytest.raises(SubdivInputError):
        ws.Refiner(grid(), 1, device="cpu", flatness=value)


def test_flatness_refuses_complex_arrays():
    """A complex array is not real: numpy would drop the imaginary parts with only a warning."""
    with pytest.raises(SubdivInputError, match="flatness must hold numbers .*complex") as info:
        Options(flatness=np.full(6, 0.5 + 0.5j))
    assert info.value.option == "flatness"


@pytest.mark.parametrize("value,expected", [
    (0.5, 0.5), (1, 1.0), (0, 0.0), (np.float32(0.5), 0.5), (np.float64(0.25), 0.25), (np.int64(1), 1.0),
    (np.array(0.5), 0.5),
])
def test_flatness_accepts_real_numbers(value, expected):
    flatness = Options(flatness=value).flatness
    assert type(flatness) is float and flatness == expected


@pytest.mark.parametrize("value", [[0.5, 0.25, float("nan"), 1, 0, 0.5], np.linspace(0, 1, 6, dtype=np.float32),
                                   np.array([0, 1, 1, 0, 1, 0], dtype=np.int32), (0.5,) * 6, [0.5, None] * 3])
def test_flatness_accepts_per_vertex_numbers(value):
    """Per-vertex numbers (NaN or None: the optimal s*) as before: a read-only float64 array."""
    flatness = Options(flatness=value).flatness
    assert flatness.dtype == np.float64 and not flatness.flags.writeable
    np.testing.assert_array_equal(flatness, np.array(value, dtype=np.float64))
    ws.Refiner(grid(), 1, device="cpu", flatness=value)


@pytest.mark.parametrize("value", NOT_NUMBERS, ids=repr)
def test_normal_strength_refuses_bools_and_strings(value):
    with pytest.raises(SubdivInputError, match="normal_strength must be a number") as info:
        Options(normal_strength=value)
    assert info.value.option == "normal_strength"


@pytest.mark.parametrize("value", [0.5, np.float32(0.5), np.int64(0), 1])
def test_normal_strength_accepts_real_numbers(value):
    strength = Options(normal_strength=value).normal_strength
    assert type(strength) is float and strength == float(value)


@pytest.mark.parametrize("name", ["triangulate", "linear"])
@pytest.mark.parametrize("value", [1, 0, "True", "yes", None, np.int64(1)], ids=repr)
def test_switches_refuse_numbers_and_strings(name, value):
    """triangulate and linear are True or False (numpy bools included), not 1/0 or a string."""
    with pytest.raises(SubdivInputError, match=f"{name} must be True or False") as info:
        Options(**{name: value})
    assert info.value.option == name
    assert getattr(Options(**{name: np.bool_(True)}), name) is True


@pytest.mark.parametrize("make", [lambda v: ws.Refiner(grid(), v, device="cpu"),
                                  lambda v: ws.refine(grid(), v, device="cpu")], ids=["Refiner", "refine"])
@pytest.mark.parametrize("levels", [True, np.bool_(True), "1", 1.0], ids=repr)
def test_levels_refuse_bools_strings_and_floats(make, levels):
    with pytest.raises(SubdivInputError, match="levels must be an integer") as info:
        make(levels)
    assert info.value.option == "levels"


@pytest.mark.parametrize("levels", [True, np.bool_(True), "1", 1.0], ids=repr)
def test_batch_levels_refuse_bools_strings_and_floats(levels):
    from warp_subdiv.batch import MeshBatch

    with pytest.raises(SubdivInputError, match="levels must be an integer") as info:
        MeshBatch([grid(), grid()], levels, device="cpu")
    assert info.value.option == "levels"


# --------------------------------------------------------------------------------------------------------
# options= and option keywords: Options.given turns them into one Options for Refiner, MeshBatch, LimitSurface

def make_refiner(**kw):
    return ws.Refiner(grid(), 1, device="cpu", **kw)


def make_refined(**kw):
    return ws.refine(grid(), 1, device="cpu", **kw)


def make_batch(**kw):
    from warp_subdiv.batch import MeshBatch

    return MeshBatch([grid(), grid()], 1, device="cpu", **kw)


def make_surface(**kw):
    return ws.LimitSurface(grid(), device="cpu", **kw)


MAKERS = {"Refiner": make_refiner, "refine": make_refined, "MeshBatch": make_batch, "LimitSurface": make_surface}


@pytest.mark.parametrize("maker", MAKERS)
@pytest.mark.parametrize("options", [{"scheme": "loop"}, "loop", ws.Options], ids=["dict", "str", "class"])
def test_options_must_be_an_options_object(maker, options):
    """A dict (or anything else) as options= used to fail deep inside with an AttributeError; it is refused
    up front, saying what to pass instead."""
    with pytest.raises(TypeError, match=r"options must be a warp_subdiv\.Options.*Options\(\*\*"):
        MAKERS[maker](options=options)


@pytest.mark.parametrize("maker", MAKERS)
def test_options_object_and_keywords_still_work(maker):
    MAKERS[maker](options=Options(boundary="edge-only"))
    MAKERS[maker](boundary="edge-only")
    with pytest.raises(TypeError, match="either options= or option keywords"):
        MAKERS[maker](options=Options(), boundary="edge-only")


@pytest.mark.parametrize("maker,callable_name", [("Refiner", "Refiner"), ("refine", "Refiner"),
                                                 ("MeshBatch", "MeshBatch"), ("LimitSurface", "LimitSurface")])
def test_unknown_option_keyword_names_the_keyword_and_the_callable(maker, callable_name):
    """A keyword that is no option used to raise Options.__init__'s TypeError, naming neither the call that
    took it nor the options there are."""
    with pytest.raises(TypeError, match=rf"{callable_name} does not take 'flatnes'.*did you mean 'flatness'.*"
                                        r"options are: scheme, rules"):
        MAKERS[maker](flatnes=0.5)


def test_limit_surface_does_not_take_threads():
    """The limit surface is built without the refiner's thread pool: threads= is refused by name (it
    used to raise Options.__init__'s 'unexpected keyword argument'), while Refiner and MeshBatch take it."""
    with pytest.raises(TypeError, match=r"LimitSurface does not take 'threads'"):
        make_surface(threads=2)
    make_refiner(threads=2)
    make_batch(threads=2)


def test_options_given_without_a_callable_name():
    with pytest.raises(TypeError, match=r"'bogus' is not an option"):
        Options.given(None, {"bogus": 1})
    assert Options.given(None, {"scheme": "loop"}) == Options(scheme="loop")
    options = Options(scheme="loop")
    assert Options.given(options, {}) is options
