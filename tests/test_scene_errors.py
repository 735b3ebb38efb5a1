"""Bad scenes get one clear error naming the file, the item and the problem."""

import subprocess
import sys

import pytest

import mbdfmu
from mbdfmu import AssemblyError, SceneError

BASE = """
name = "T"
[[body]]
name = "crank"
mass = 1.0
inertia = 0.1
position = [0.5, 0.0]
angle = 0.0
[[joint]]
name = "O"
type = "revolute"
body_i = "ground"
point_i = [0.0, 0.0]
body_j = "crank"
point_j = [-0.5, 0.0]
"""

CASES = {
    "invalid_toml": (BASE + "mass = = 3\n", ["bad.toml", "invalid TOML"]),
    "unknown_key": (BASE.replace("mass = 1.0", "mass = 1.0\nmas = 2.0"),
                    ['body "crank"', 'unknown key "mas"', 'did you mean "mass"']),
    "missing_key": (BASE.replace("inertia = 0.1\n", ""),
                    ['body "crank"', 'missing required key "inertia"']),
    "unknown_body": (BASE.replace('body_j = "crank"', 'body_j = "crankk"'),
                     ['joint "O"', 'unknown body "crankk"', 'did you mean "crank"']),
    "unknown_joint": (BASE + '[[driver]]\nname = "m"\njoint = "P"\nmotion = {type = "constant", value = 0.0}\n',
                      ['driver "m"', 'unknown joint "P"']),
    "duplicate": (BASE + '[[body]]\nname = "crank"\nmass = 1.0\ninertia = 1.0\nposition = [0.0, 0.0]\n',
                  ['body "crank"', "duplicate name"]),
    "force_on_ground": (BASE + '[[force]]\nname = "F"\ntype = "torque"\nbody = "ground"\nvalue = 1.0\n',
                        ['force "F"', "acts on the ground"]),
    "duplicate_across_kinds": (BASE + '[[force]]\nname = "O"\ntype = "torque"\nbody = "crank"\nvalue = 1.0\n',
                               ['force "O"', "duplicate name (also a joint)"]),
    "nonpositive_mass": (BASE.replace("mass = 1.0", "mass = 0.0"),
                         ['body "crank"', '"mass" must be positive']),
    "negative_inertia": (BASE.replace("inertia = 0.1", "inertia = -1.0"),
                         ['body "crank"', '"inertia" must be positive']),
    "non_finite": (BASE.replace("angle = 0.0", "angle = nan"),
                   ['body "crank"', '"angle" must be finite']),
    "infinite_vector": (BASE.replace("position = [0.5, 0.0]", "position = [inf, 0.0]"),
                        ['body "crank"', '"position" must be finite']),
    "zero_axis": (BASE + '[[joint]]\nname = "g"\ntype = "translational"\nbody_i = "ground"\n'
                  'axis_i = [0.0, 0.0]\nbody_j = "crank"\n', ['joint "g"', '"axis_i" has zero length']),
    "unknown_joint_type": (BASE.replace('type = "revolute"', 'type = "revolut"'),
                           ['joint "O"', 'unknown joint type "revolut"', 'did you mean "revolute"']),
    "unknown_force_type": (BASE + '[[force]]\nname = "f"\ntype = "spring"\n',
                           ['force "f"', 'unknown force type "spring"']),
    "unknown_motion_type": (BASE + '[[driver]]\nname = "m"\njoint = "O"\nmotion = {type = "sine"}\n',
                            ['driver "m"', 'unknown motion type "sine"']),
    "bad_identifier": (BASE.replace('name = "T"', 'name = "my model"'), ['"my model"', "identifier"]),
    "wrong_type": (BASE.replace("mass = 1.0", 'mass = "heavy"'), ['body "crank"', '"mass" must be a number']),
}

# The new joints (couplers, slots, rolling discs): a disc of radius 0.5 whose centre sits at
# (0, 0.5), above a ground line along x, and couplers on the crank's joint.
DISC = '[[body]]\nname = "disc"\nmass = 1.0\ninertia = 0.1\nposition = [0.0, 0.5]\n'
ROLLING = ('[[joint]]\nname = "r"\ntype = "rolling"\nbody_i = "ground"\naxis_i = [1.0, 0.0]\n'
           'body_j = "disc"\nradius = 0.5\n')
SLOT = ('[[joint]]\nname = "s"\ntype = "slot"\nbody_i = "ground"\naxis_i = [1.0, 0.0]\n'
        'body_j = "disc"\npoint_j = [0.0, -0.5]\n')
TRACK = ('[[joint]]\nname = "g"\ntype = "translational"\nbody_i = "ground"\n'
         'axis_i = [1.0, 0.0]\nbody_j = "disc"\n')


def _coupler(joint_i='"O"', joint_j='"g"', ratio="0.1", extra=""):
    return (BASE + DISC + TRACK + SLOT + f'[[joint]]\nname = "c"\ntype = "coupler"\n'
            f"joint_i = {joint_i}\njoint_j = {joint_j}\nratio = {ratio}\n{extra}")


CASES |= {
    "coupler_unknown_joint": (_coupler(joint_i='"P"'),
                              ['joint "c"', 'joint_i: unknown joint "P"']),
    "coupler_itself": (_coupler(joint_j='"O"'), ['joint "c"', 'couples joint "O" to itself']),
    "coupler_no_coordinate": (_coupler(joint_j='"s"'),
                              ['joint "c"', 'joint_j: joint "s" is slot, which has no coordinate']),
    "coupler_zero_ratio": (_coupler(ratio="0.0"), ['joint "c"', '"ratio" must not be zero']),
    "coupler_ratio_not_a_number": (_coupler(ratio='"2:1"'),
                                   ['joint "c"', '"ratio" must be a number']),
    "coupler_missing_ratio": (_coupler().replace("ratio = 0.1\n", ""),
                              ['joint "c"', 'missing required key "ratio"']),
    "coupler_body_key": (_coupler(extra='body_i = "crank"\n'),
                         ['joint "c"', 'unknown key "body_i"']),
    "rolling_negative_radius": (BASE + DISC + ROLLING.replace("radius = 0.5", "radius = -0.5"),
                                ['joint "r"', '"radius" must be positive, got -0.5']),
    "rolling_off_its_radius": (BASE + DISC + ROLLING.replace("radius = 0.5", "radius = 0.4"),
                               ['joint "r"', 'the centre of body "disc" starts 0.5 m from the line',
                                "not at the radius 0.4 m"]),
    "rolling_on_the_right": (BASE + DISC.replace("[0.0, 0.5]", "[0.0, -0.5]") + ROLLING,
                             ['joint "r"', "starts -0.5 m from the line"]),
    "rolling_point_j": (BASE + DISC + ROLLING + "point_j = [0.1, 0.0]\n",
                        ['joint "r"', 'unknown key "point_j"']),
    "rolling_disc_is_ground": (BASE + ROLLING.replace('body_i = "ground"', 'body_i = "crank"')
                               .replace('body_j = "disc"', 'body_j = "ground"'),
                               ['joint "r"', "body_j: acts on the ground"]),
    "rolling_zero_axis": (BASE + DISC + ROLLING.replace("[1.0, 0.0]", "[0.0, 0.0]"),
                          ['joint "r"', '"axis_i" has zero length']),
    "slot_zero_axis": (BASE + DISC + SLOT.replace("[1.0, 0.0]", "[0.0, 0.0]"),
                       ['joint "s"', '"axis_i" has zero length']),
    "slot_missing_axis": (BASE + DISC + SLOT.replace("axis_i = [1.0, 0.0]\n", ""),
                          ['joint "s"', 'missing required key "axis_i"']),
    "driver_on_rolling": (BASE + DISC + ROLLING + '[[driver]]\nname = "m"\njoint = "r"\n'
                          'motion = {type = "constant", value = 0.0}\n',
                          ['driver "m"', 'joint "r" is rolling, which has no coordinate']),
}


def _write(tmp_path, text):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_scene_is_reported_with_file_item_and_problem(tmp_path, case):
    text, fragments = CASES[case]
    with pytest.raises(SceneError) as info:
        mbdfmu.load_scene(_write(tmp_path, text))
    message = str(info.value)
    assert message.startswith("bad.toml")
    for fragment in fragments:
        assert fragment in message


def test_every_problem_is_reported_at_once(tmp_path):
    text = BASE.replace("mass = 1.0", "mass = -1.0").replace('body_j = "crank"', 'body_j = "x"')
    with pytest.raises(SceneError) as info:
        mbdfmu.load_scene(_write(tmp_path, text))
    assert len(info.value.problems) == 2


def test_scene_that_cannot_be_assembled_names_the_violated_constraint(tmp_path):
    # A 1 m crank whose tip must reach a point 3 m away.
    text = BASE + ('[[joint]]\nname = "tip"\ntype = "revolute"\nbody_i = "ground"\n'
                   'point_i = [3.0, 0.0]\nbody_j = "crank"\npoint_j = [0.5, 0.0]\n')
    with pytest.raises(AssemblyError) as info:
        mbdfmu.simulate(mbdfmu.load_scene(_write(tmp_path, text)), 0.1)
    assert "bad.toml" in str(info.value) and 'joint "' in str(info.value)
    assert "cannot be assembled" in str(info.value)


def test_inconsistent_redundant_constraints_are_named(tmp_path):
    # The same crank point pinned to two ground points 0.1 m apart: both joints give the
    # same Jacobian rows (redundant) with different right-hand sides (inconsistent).
    text = BASE + ('[[joint]]\nname = "O2"\ntype = "revolute"\nbody_i = "ground"\n'
                   'point_i = [0.1, 0.0]\nbody_j = "crank"\npoint_j = [-0.5, 0.0]\n')
    with pytest.raises(AssemblyError) as info:
        mbdfmu.simulate(mbdfmu.load_scene(_write(tmp_path, text)), 0.1)
    message = str(info.value)
    assert "redundant and inconsistent" in message and 'joint "O2"' in message


def test_consistent_redundant_constraints_are_reported_not_rejected(scenes_dir):
    from mbdfmu.equations.projection import assemble, rank_report
    from mbdfmu.equations import Equations

    system = Equations(mbdfmu.load_scene(scenes_dir / "parallelogram.toml"))
    q, _ = assemble(system)
    report = rank_report(system, 0.0, q)
    assert (report.dof, len(report.redundant)) == (1, 1)


@pytest.mark.parametrize("case", ["unknown_key", "invalid_toml", "zero_axis", "coupler_itself",
                                  "rolling_off_its_radius"])
def test_cli_exits_2_with_one_line_and_no_traceback(tmp_path, case):
    path = _write(tmp_path, CASES[case][0])
    for command in (["check", str(path)], ["simulate", str(path), "--t-end", "0.1"]):
        proc = subprocess.run([sys.executable, "-m", "mbdfmu.cli", *command],
                              capture_output=True, text=True)
        assert proc.returncode == 2
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in proc.stderr
        assert "bad.toml" in lines[0]
