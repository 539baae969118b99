"""ecp.Scene: from a TOML file, TOML text and a dict; bad input raises ecp.InputError with the
message `ecp check` prints (file, key, line); parameters; pickling."""

import math
import pickle

import numpy as np
import pytest

import ecp
from conftest import run_cli, scene_path

A1_DICT = {
    "name": "a1_dict",
    "simulation": {"h": 0.01, "duration": 0.1, "gravity": [0, 0, -9.8]},
    "friction": {"mu": 0.3, "e_t": 1.0, "e_o": 1.0, "e_r": 0.1},
    "half_spaces": [{"normal": (0, 0, 1), "offset": 0}],
    "bodies": [
        {
            "name": "box",
            "mass": 10,
            "inertia": "uniform",
            "position": np.array([0.0, 0.0, 0.1]),
            "velocity": [1, 0, 0],
            "pieces": [{"box": [0.4, 0.4, 0.2]}],
        }
    ],
}


MU_LINE = scene_path("a1_sliding").read_text().splitlines().index("mu = 0.3") + 1


def a1_dict(**body):
    d = {k: (dict(v) if isinstance(v, dict) else v) for k, v in A1_DICT.items()}
    d["bodies"] = [dict(A1_DICT["bodies"][0], **body)]
    return d


def test_a_scene_file_loads_with_its_settings(desk):
    assert desk.name == "desk"
    assert desk.h == 0.01 and desk.duration == 4.0 and desk.num_steps == 400
    assert desk.bodies == ["desk"]
    assert desk.formulation == "hull" and desk.solver == "newton"
    assert desk.get_param("mu") == 0.22 and desk.get_param("e_r") == 0.1
    assert desk.get_param("mass") == 15.0
    assert "desk" in desk.describe()


def test_a_dict_builds_the_same_scene_as_the_file():
    from_dict = ecp.Scene.from_dict(a1_dict())
    from_file = ecp.Scene.from_toml(scene_path("a1_sliding"))
    a = ecp.Simulation(from_dict).run(10)
    b = ecp.Simulation(from_file).run(10)
    assert a.states.tobytes() == b.states.tobytes()
    # A1: v = 1 − μ g h k.
    assert abs(a.velocity[-1, 0, 0] - (1 - 0.3 * 9.8 * 0.01 * 10)) < 1e-9


def test_none_leaves_a_key_out():
    s = ecp.Scene.from_dict(a1_dict(orientation=None, angular_velocity=None))
    assert s.get_param("qw0") == 1.0 and s.get_param("wz0") == 0.0


def cli_message(path):
    """What `ecp check PATH` prints after "error: "."""
    out = run_cli("check", str(path))
    assert out.returncode == 2, out
    line = out.stderr.strip()
    assert line.startswith("error: ")
    return line[len("error: "):]


def test_a_missing_file_raises_the_cli_message(tmp_path):
    missing = tmp_path / "nope.toml"
    with pytest.raises(ecp.InputError) as e:
        ecp.Scene.from_toml(missing)
    assert "nope.toml" in str(e.value) and "file missing" in str(e.value)
    assert isinstance(e.value, ValueError)
    assert str(e.value) == cli_message(missing)


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda t: t.replace("mu = 0.3", "mu = [0.3"), ["syntax error", "line"]),
        (lambda t: t.replace("mu = 0.3", "muu = 0.3"), ["unknown key", "friction.muu", f"line {MU_LINE}"]),
        (lambda t: t.replace("mass = 10.0", 'mass = "ten"'), ["wrong type", "bodies[0].mass", "line"]),
        (lambda t: t.replace("mass = 10.0", "mass = nan"), ["invalid value", "bodies[0].mass", "finite"]),
        (lambda t: t.replace("mass = 10.0", "mass = -1.0"), ["invalid value", "bodies[0].mass", "> 0"]),
    ],
)
def test_bad_toml_raises_the_cli_message_with_file_key_and_line(tmp_path, edit, words):
    text = scene_path("a1_sliding").read_text()
    bad = edit(text)
    assert bad != text
    path = tmp_path / "bad.toml"
    path.write_text(bad)
    with pytest.raises(ecp.InputError) as e:
        ecp.Scene.from_toml(path)
    message = str(e.value)
    assert message.startswith(str(path))
    for w in words:
        assert w in message, message
    assert message == cli_message(path)
    # The same text from a string names the path given.
    with pytest.raises(ecp.InputError) as e2:
        ecp.Scene.from_string(bad, path)
    assert str(e2.value) == message


@pytest.mark.parametrize(
    "body, words",
    [
        ({"mass": "ten"}, ["<dict>", "key `bodies[0].mass`", "wrong type"]),
        ({"mass": float("nan")}, ["key `bodies[0].mass`", "invalid value", "not a finite number"]),
        ({"mass": 10, "colour": "red"}, ["unknown key", "colour"]),
        ({"position": [0, 0]}, ["bodies[0].position", "wrong type"]),
        ({"velocity": [1, float("inf"), 0]}, ["bodies[0].velocity", "finite"]),
    ],
)
def test_bad_dicts_raise_input_errors_naming_the_key(body, words):
    with pytest.raises(ecp.InputError) as e:
        ecp.Scene.from_dict(a1_dict(**body))
    for w in words:
        assert w in str(e.value), str(e.value)
    assert "line" not in str(e.value), "a dict has no lines"


def test_values_a_scene_cannot_hold_raise_type_errors():
    with pytest.raises(TypeError, match="bodies.0..mass|bodies\\[0\\].mass"):
        ecp.Scene.from_dict(a1_dict(mass=object()))
    with pytest.raises(TypeError, match="dict"):
        ecp.Scene.from_dict([1, 2, 3])
    with pytest.raises(TypeError, match="strings"):
        ecp.Scene.from_dict({1: 2})


def test_with_params_returns_a_checked_copy(a1):
    b = a1.with_params(mu=0.1, vx0=2.0)
    assert (b.get_param("mu"), b.get_param("vx0")) == (0.1, 2.0)
    assert a1.get_param("mu") == 0.3, "the original is unchanged"
    c = a1.with_params({"mass": 20.0, "fx": 5.0})
    assert c.get_param("mass") == 20.0 and c.get_param("fx") == 5.0
    with pytest.raises(ecp.InputError, match="μ must be ≥ 0"):
        a1.with_params(mu=-0.1)
    with pytest.raises(ecp.InputError, match="finite"):
        a1.with_params(e_r=math.nan)
    with pytest.raises(ecp.InputError, match="unknown parameter"):
        a1.with_params(friction=0.2)
    with pytest.raises(ecp.InputError, match="names body 1"):
        a1.get_param("mass[1]")
    with pytest.raises(TypeError, match="expected a number"):
        a1.with_params(mu="high")


def test_a_scene_pickles_with_its_parameters(desk):
    changed = desk.with_params(mu=0.3)
    back = pickle.loads(pickle.dumps(changed))
    assert back.get_param("mu") == 0.3 and back.name == "desk"
    a = ecp.Simulation(back).run(20)
    b = ecp.Simulation(changed).run(20)
    assert a.states.tobytes() == b.states.tobytes()
    d = pickle.loads(pickle.dumps(ecp.Scene.from_dict(a1_dict())))
    assert d.name == "a1_dict"
