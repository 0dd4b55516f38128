"""One typed Options object from the flag to the solver: validation, the CLI table, the API signature."""

import argparse
import dataclasses
import inspect
from pathlib import Path

import pytest

import meshreg
from meshreg.errors import InputError
from meshreg.flags import FLAGS, add_flags, options_from_args
from meshreg.options import Advanced, Options

REGISTRATION_FIELDS = {f.name for f in dataclasses.fields(Options)} - {"advanced"}


def test_register_signature_shows_every_registration_option_with_its_default():
    params = inspect.signature(meshreg.register).parameters
    keyword = {n: p for n, p in params.items() if n not in ("first", "second", "callback")}
    assert set(keyword) == REGISTRATION_FIELDS | {"advanced"}
    defaults = Options()
    for name in REGISTRATION_FIELDS:
        assert keyword[name].default == getattr(defaults, name), name
    assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for n, p in keyword.items() if n != "mode")
    assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())


def test_every_flag_sets_an_existing_field():
    names = {f.name for f in dataclasses.fields(Options)}
    advanced = {f.name for f in dataclasses.fields(Advanced)}
    for row in FLAGS:
        if row.field.startswith("advanced."):
            assert row.field.split(".", 1)[1] in advanced, row.flag
        else:
            assert row.field in names, row.flag


def test_flags_parse_into_options_and_defaults_come_from_options():
    parser = argparse.ArgumentParser()
    add_flags(parser)
    given = parser.parse_args(
        [
            "--mode",
            "dp+gd",
            "--window",
            "7",
            "--max-rounds",
            "3",
            "--smoothing",
            "--no-cleanup",
            "--corners1",
            "1",
            "2",
            "3",
            "4",
        ]
    )
    opts = options_from_args(given)
    assert (opts.mode, opts.window, opts.advanced.max_rounds, opts.smoothing, opts.cleanup, opts.corners1) == (
        "dp+gd",
        7,
        3,
        (),
        False,
        (1, 2, 3, 4),
    )
    assert options_from_args(parser.parse_args([])) == Options()


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"mode": "fast"}, "unknown mode"),
        ({"window": 0}, "window"),
        ({"basis": 0}, "basis"),
        ({"basis": 1000}, "basis"),
        ({"start_basis": 0}, "start_basis"),
        ({"max_starts": 0}, "max_starts"),
        ({"symmetry": 8}, "symmetry"),
        ({"symmetry": 1.5}, "symmetry"),
        ({"antialias": 0}, "antialias"),
        ({"smoothing": (0.0,)}, "smoothing"),
        ({"smoothing": (float("nan"),)}, "smoothing"),
        ({"resolution": -5}, "resolution"),
        ({"corners1": (1, 2, 3)}, "corners1"),
        ({"weights": "uniform"}, "unknown weights"),
        ({"window": 2.5}, "window"),
        ({"bend_window": -0.1}, "bend_window"),
        ({"bend_window": 2.0}, "bend_window"),
    ],
)
def test_bad_options_name_the_field_and_the_valid_range(changes, message):
    with pytest.raises(InputError, match=message):
        Options(**changes)


@pytest.mark.parametrize(
    "changes",
    [
        {"dp_rounds": 0},
        {"damping": float("nan")},
        {"max_iterations": -1},
        {"step_fraction": 100.0},
        {"rel_tol": float("nan")},
        {"max_rounds": -1},
        {"choice_window": 0.0},
        {"refine_triangles": -1.0},
        {"ambiguity": -0.5},
    ],
)
def test_bad_advanced_numerics_are_refused(changes):
    name = next(iter(changes))
    with pytest.raises(InputError, match=name):
        Advanced(**changes)


def test_options_record_every_field_in_the_result():
    from meshreg.samples import paper_pairs

    pair = paper_pairs(11, 11)[0]
    result = meshreg.register(pair.first, pair.second, mode="dp", window=4, advanced=Advanced(dp_rounds=2))
    assert result.params["window"] == 4 and result.params["dp_rounds"] == 2 and result.params["mode"] == "dp"
    assert set(result.params) >= {f.name for f in dataclasses.fields(Advanced)}


def test_register_stays_the_function_once_the_pipeline_module_is_loaded():
    import meshreg.mesh.correspond  # noqa: F401  (imports meshreg.pipeline, the module behind meshreg.register)

    assert callable(meshreg.register) and meshreg.register.__name__ == "register"


def test_every_option_is_in_the_parameter_tables():
    """docs/method.md's tables name every field of Options and Advanced (a field added without them fails)."""
    doc = (Path(__file__).parents[1] / "docs" / "method.md").read_text()
    missing = [f.name for c in (Options, Advanced) for f in dataclasses.fields(c) if f"| `{f.name}`" not in doc]
    assert not missing, missing
