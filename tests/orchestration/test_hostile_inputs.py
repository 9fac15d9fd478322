"""Hostile scenes: every one is refused at load with a SceneError naming the scene file and the key
(or file) at fault; none raises anything else (no TypeError, no MemoryError, no traceback later).

Each case edits a valid scene file (a small tower on a disk; loading it runs no BEM and no route).
"""
import copy

try:
    import tomllib
except ModuleNotFoundError:  # Python < 3.11
    import tomli as tomllib

import pytest

from orchestrator.scene import SceneError, load_scene, scene_from_dict

SCENE = """\
[soil]
halfspace = { vs = 500.0, nu = 0.3, rho = 2000.0 }
[foundation]
shape = "circle"
radius = 5.0
element_size = 2.5
[impedance]
frequencies_hz = [0.0, 2.0]
[structure]
nodes = [ { id = 1, xyz = [0, 0, 0] }, { id = 2, xyz = [0, 0, 20], name = "top" } ]
beams = [ { nodes = [1, 2], E = 3e10, G = 1.25e10, A = 10.0, Iy = 20.0, Iz = 20.0, J = 40.0 } ]
masses = [ { node = 2, m = 2.0e6 } ]
raft = { node = 1, m = 1.0e6 }
[contact]
enabled = true
[motion]
kind = "synthetic"
pga_g = 0.3
duration_s = 3.0
seed = 2
[analysis]
routes = ["winkler"]
dt = 0.01
[output]
nodes = ["top"]
"""

SYNTHETIC = 'kind = "synthetic"\npga_g = 0.3\nduration_s = 3.0\nseed = 2\n'
AT2_HEAD = "PEER\nEQ\nACCELERATION TIME SERIES IN UNITS OF G\n"
TWO_COLUMN = "".join(f"{0.01 * k:.2f} 0.1\n" for k in range(100))


def record(fmt="two-column", extra=""):
    return (SYNTHETIC, f'kind = "record"\nfile = "rec.dat"\nformat = "{fmt}"\n{extra}')


# id: ([(old, new), ...] edits of SCENE, {file name: bytes}, substring of the message)
CASES = {
    # wrong types
    "duration-string": ([("duration_s = 3.0", 'duration_s = "2"')], {}, "motion.duration_s = '2' must be"),
    "frequency-bool": ([("frequencies_hz = [0.0, 2.0]", "frequencies_hz = [true, 1.0]")], {},
                       "impedance.frequencies_hz[0] = True must be a finite number"),
    "frequencies-string": ([("frequencies_hz = [0.0, 2.0]", 'frequencies_hz = "0 2"')], {},
                           "impedance.frequencies_hz = '0 2' must be a non-empty list"),
    "seed-float": ([("seed = 2", "seed = 2.7")], {}, "motion.seed = 2.7 must be an integer"),
    "seed-bool": ([("seed = 2", "seed = true")], {}, "motion.seed = True must be an integer"),
    "dt-string": ([("dt = 0.01", 'dt = "0.01"')], {}, "analysis.dt = '0.01' must be a step"),
    "routes-string": ([('routes = ["winkler"]', 'routes = "winkler"')], {},
                      "analysis.routes = 'winkler' must be a non-empty list"),
    "output-string": ([('nodes = ["top"]', 'nodes = "top"')], {}, "output.nodes = 'top' must be a non-empty list"),
    "output-number": ([('nodes = ["top"]', "nodes = [1]")], {}, "output.nodes = [1] must be a non-empty list"),
    "vs-string": ([("vs = 500.0", 'vs = "fast"')], {}, "soil.halfspace.vs = 'fast' must be a finite number"),
    "layers-number": ([("[soil]\n", "[soil]\nlayers = 5\n")], {}, "soil.layers must be a list of tables"),
    "layer-number": ([("[soil]\n", "[soil]\nlayers = [5]\n")], {}, "soil.layers[0] must be a table"),
    "shape-list": ([('shape = "circle"', 'shape = ["circle"]')], {}, "foundation.shape = ['circle']: use one of"),
    "section-not-table": ([("[soil]\n", "motion = 5\n[soil]\n"), ("[motion]\n" + SYNTHETIC, "")], {},
                          "[motion] must be a table of keys (a section), got motion = 5"),
    "contact-enabled-string": ([("enabled = true", 'enabled = "yes"')], {},
                               "contact.enabled = 'yes' must be true or false"),
    "beam-E-bool": ([("E = 3e10", "E = true")], {}, "structure.beams[0].E = True must be a finite number"),
    "node-id-float": ([("id = 2,", "id = 2.5,")], {}, "structure.nodes[1].id = 2.5 must be an integer node id"),
    # out of range
    "pga-negative": ([("pga_g = 0.3", "pga_g = -0.1")], {}, "motion.pga_g = -0.1 must be"),
    "pga-nan": ([("pga_g = 0.3", "pga_g = nan")], {}, "motion.pga_g = nan must be"),
    "duration-inf": ([("duration_s = 3.0", "duration_s = inf")], {}, "motion.duration_s = inf must be"),
    "duration-huge": ([("duration_s = 3.0", "duration_s = 1e9")], {},
                      "motion.duration_s = 1e+09 s makes 2e+11 time steps; at most MAX_STEPS"),
    "duration-short": ([("duration_s = 3.0", "duration_s = 0.05")], {}, "motion.duration_s = 0.05 s is too short"),
    "seed-negative": ([("seed = 2", "seed = -1")], {}, "motion.seed = -1 must be an integer >= 0"),
    "dt-zero": ([("dt = 0.01", "dt = 0.0")], {}, "analysis.dt = 0.0 must be a step in (0, 0.05]"),
    "dt-large": ([("dt = 0.01", "dt = 0.5")], {}, "analysis.dt = 0.5 must be a step in (0, 0.05]"),
    "fit-tol": ([("dt = 0.01", "dt = 0.01\nfit_tol = 1.5")], {}, "analysis.fit_tol = 1.5 must be"),
    "timefreq-budget": ([("dt = 0.01", "dt = 0.01\ntimefreq_max_s = -1")], {},
                        "analysis.timefreq_max_s = -1 must be a positive number of seconds"),
    "route-unknown": ([('routes = ["winkler"]', 'routes = ["fem"]')], {}, "analysis.routes: unknown route 'fem'"),
    "route-twice": ([('routes = ["winkler"]', 'routes = ["winkler", "winkler"]')], {}, "lists 'winkler' twice"),
    "routes-empty": ([('routes = ["winkler"]', "routes = []")], {}, "analysis.routes = [] must be a non-empty list"),
    "output-unknown-node": ([('nodes = ["top"]', 'nodes = ["roof"]')], {},
                            "output.nodes: 'roof' is not a named structure node; named nodes: top"),
    "beam-E-negative": ([("E = 3e10", "E = -3")], {}, "structure.beams[0].E = -3 must be > 0"),
    "contact-penalty": ([("enabled = true", "penalty = -1.0")], {}, "contact.penalty = -1.0 must be > 0"),
    "frequencies-decreasing": ([("frequencies_hz = [0.0, 2.0]", "frequencies_hz = [2.0, 1.0]")], {},
                               "strictly increasing"),
    "range-count-huge": ([("frequencies_hz = [0.0, 2.0]", "range_hz = [0.0, 25.0, 1000000000000]")], {},
                         "impedance.range_hz[2] = 1000000000000 must be an integer count"),
    "range-count-float": ([("frequencies_hz = [0.0, 2.0]", "range_hz = [0.0, 25.0, 11.0]")], {},
                          "impedance.range_hz[2] = 11.0 must be an integer count"),
    "range-fmax-inf": ([("frequencies_hz = [0.0, 2.0]", "range_hz = [0.0, inf, 11]")], {},
                       "impedance.range_hz[1] = inf must be a frequency fmax"),
    "damping-model": ([("[soil]\n", '[soil]\ndamping_model = "Causal"\n')], {},
                      "soil.damping_model = 'Causal': use one of"),
    "poisson": ([("nu = 0.3", "nu = 0.5")], {}, "nu = 0.5 must lie in (0, 0.5)"),
    # misspelt keys, every section
    "typo-motion": ([("seed = 2", "sed = 2")], {}, "unknown key motion.sed: did you mean 'seed'?"),
    "typo-analysis": ([('routes = ["winkler"]', 'rutes = ["winkler"]')], {},
                      "unknown key analysis.rutes: did you mean 'routes'?"),
    "typo-output": ([('nodes = ["top"]', 'node = ["top"]')], {}, "unknown key output.node: did you mean 'nodes'?"),
    "typo-structure": ([("masses = [", "mases = [")], {}, "unknown key structure.mases: did you mean 'masses'?"),
    "typo-beam": ([("J = 40.0", "JJ = 40.0")], {}, "unknown key structure.beams[0].JJ"),
    "typo-contact": ([("enabled = true", "enabeld = true")], {},
                     "unknown key contact.enabeld: did you mean 'enabled'?"),
    "typo-foundation": ([("radius = 5.0", "radus = 5.0")], {}, "unknown key foundation.radus: did you mean 'radius'?"),
    "typo-impedance": ([("frequencies_hz", "frequency_hz")], {}, "unknown key impedance.frequency_hz"),
    "typo-halfspace": ([("rho = 2000.0", "rh = 2000.0")], {}, "unknown key soil.halfspace.rh"),
    "typo-winkler": ([("[soil]\n", "[soil]\nwinkler = { spring = \"rigid\" }\n")], {},
                     "unknown key soil.winkler.spring: did you mean 'springs'?"),
    "typo-section": ([("[output]", "[outputs]")], {}, "unknown section scene.outputs: did you mean 'output'?"),
    "winkler-mixed": ([("[soil]\n", '[soil]\nwinkler = { kv = 1e8, kh = 1e8, springs = "rigid" }\n')], {},
                      "soil.winkler: give either subgrade moduli"),
    "winkler-choice": ([("[soil]\n", '[soil]\nwinkler = { damping = "viscous" }\n')], {},
                       "soil.winkler.damping = 'viscous': use one of \"rccg\", \"dashpots\""),
    "halfspace-for-bem-routes": ([("halfspace = { vs = 500.0, nu = 0.3, rho = 2000.0 }",
                                 "winkler = { kv = 1e8, kh = 1e8 }"),
                                  ('routes = ["winkler"]', 'routes = ["winkler", "linear", "timefreq"]')], {},
                                 "soil.halfspace is missing: routes linear, timefreq need the BEM soil"),
    "synthetic-key-on-record": ([record(extra="pga_g = 0.3\n")], {"rec.dat": TWO_COLUMN.encode()},
                                "unknown key motion.pga_g: allowed: kind, direction, file"),
    "record-without-file": ([(SYNTHETIC, 'kind = "record"\n')], {}, "motion.file is missing for kind = \"record\""),
    "record-file-number": ([(SYNTHETIC, 'kind = "record"\nfile = 5\n')], {}, "motion.file = 5 must be a path"),
    # absurd meshes
    "mesh-absurd": ([("element_size = 2.5", "element_size = 0.01")], {},
                    "foundation.element_size = 0.01 m on a disk of radius 5 m gives about 7.85e+05 interface nodes"),
    "mesh-zero": ([("element_size = 2.5", "element_size = 0.0")], {},
                  "foundation.element_size = 0.0 must be a positive"),
    "mesh-negative": ([("element_size = 2.5", "element_size = -1.0")], {}, "foundation.element_size = -1.0 must be"),
    "mesh-nan": ([("element_size = 2.5", "element_size = nan")], {}, "foundation.element_size = nan must be"),
    "mesh-too-coarse": ([("element_size = 2.5", "element_size = 50.0")], {}, "exceeds the radius"),
    "rectangle-too-coarse": ([('shape = "circle"\nradius = 5.0', 'shape = "rectangle"\nlx = 4.0\nly = 2.0'),
                              ("element_size = 2.5", "element_size = 5.0")], {}, "exceeds the rectangle"),
    "rectangle-absurd": ([('shape = "circle"\nradius = 5.0', 'shape = "rectangle"\nlx = 40.0\nly = 40.0'),
                          ("element_size = 2.5", "element_size = 1e-300")], {},
                         "foundation.element_size = 1e-300 m lies outside the plausible range [0.001, 1000] m"),
    "nodes-csv-not-utf8": ([('shape = "circle"\nradius = 5.0\nelement_size = 2.5', 'shape = "nodes"\nfile = "n.csv"')],
                           {"n.csv": b"x,y,area\n0,0,\xff\n"}, "foundation.file = 'n.csv'"),
    "nodes-csv-too-many": ([('shape = "circle"\nradius = 5.0\nelement_size = 2.5', 'shape = "nodes"\nfile = "n.csv"')],
                           {"n.csv": ("x,y,area\n" + "".join(f"{k},0,1\n" for k in range(5001))).encode()},
                           "the interface mesh has 5001 nodes; at most MAX_NODES = 5000"),
    "nodes-csv-missing": ([('shape = "circle"\nradius = 5.0\nelement_size = 2.5', 'shape = "nodes"\nfile = "n.csv"')],
                          {}, "foundation.file = "),
    # records
    "record-missing": ([record()], {}, "motion.file = "),
    "record-huge": ([record()], {"rec.dat": b"0 0\n1e6 0.1\n"},
                    "motion.file: the record lasts 1e+06 s makes 1e+08 time steps"),
    "record-not-utf8": ([record()], {"rec.dat": b"0 0\n0.01 \xff\xfe\n"}, "rec.dat, line 2: byte 0xff is not UTF-8"),
    "record-not-numeric": ([record()], {"rec.dat": b"0 0\n0.01 0.1\n0.02 x\n"}, "rec.dat, line 3: '0.02 x' is not"),
    "record-uneven-step": ([record()], {"rec.dat": (TWO_COLUMN + "1.50 0.1\n").encode()},
                           "rec.dat, line 101: time step"),
    "record-short": ([record()], {"rec.dat": b"0 0\n0.01 0.1\n"}, "the record lasts 0.01 s, under 20 steps"),
    "record-scale-zero": ([record(extra="scale = 0.0\n")], {"rec.dat": TWO_COLUMN.encode()},
                          "motion.scale = 0.0 must be a finite nonzero factor"),
    "record-units": ([record(extra='units = "gal"\n')], {"rec.dat": TWO_COLUMN.encode()},
                     "motion.units = 'gal': use one of"),
    "record-format": ([record(fmt="csv")], {"rec.dat": TWO_COLUMN.encode()}, "motion.format = 'csv': use one of"),
    "at2-dt-zero": ([record("peer-at2")], {"rec.dat": (AT2_HEAD + "NPTS=   3, DT=   0.0 SEC\n.1 .2 .3\n").encode()},
                    "rec.dat, line 4: DT = 0 must be a time step > 0 s"),
    "at2-dt-negative": ([record("peer-at2")], {"rec.dat": (AT2_HEAD + "NPTS= 3, DT= -.01\n.1 .2 .3\n").encode()},
                        "line 4: DT = -0.01 must be"),
    "at2-dt-nan": ([record("peer-at2")], {"rec.dat": (AT2_HEAD + "NPTS= 3, DT= NaN\n.1 .2 .3\n").encode()},
                   "line 4: DT = nan must be"),
    "at2-npts-nan": ([record("peer-at2")], {"rec.dat": (AT2_HEAD + "NPTS= nan, DT= .01\n.1 .2 .3\n").encode()},
                     "line 4: NPTS = nan must be"),
    "at2-npts-mismatch": ([record("peer-at2")], {"rec.dat": (AT2_HEAD + "NPTS= 100, DT= .01\n.1 .2 .3\n").encode()},
                          "header says NPTS = 100 but 3 values follow"),
    # the file itself
    "toml-malformed": ([("seed = 2", "seed = = 2")], {}, "is not valid TOML"),
    "toml-duplicate-key": ([("seed = 2", "seed = 2\nseed = 3")], {}, "is not valid TOML"),
}


@pytest.mark.parametrize("edits, files, message", CASES.values(), ids=CASES.keys())
def test_hostile_scene_is_refused_naming_the_key(tmp_path, edits, files, message):
    text = SCENE
    for old, new in edits:
        assert old in text, old          # the edit applies: the case is really hostile
        text = text.replace(old, new)
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
    path = tmp_path / "hostile.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as ei:
        load_scene(path)
    assert str(ei.value).startswith(f"scene file {str(path)!r}") and message in str(ei.value), str(ei.value)


def test_the_base_scene_and_its_record_variants_load(tmp_path):
    """The cases above fail because of their edit, not because the base scene is invalid."""
    path = tmp_path / "ok.toml"
    path.write_text(SCENE)
    s = load_scene(path)
    assert s.output.nodes == ("top",) and s.motion.seed == 2 and s.mesh.n > 1
    (tmp_path / "rec.dat").write_text(TWO_COLUMN)
    path.write_text(SCENE.replace(*record()))
    assert load_scene(path).motion.record.acc.shape == (100, 3)
    (tmp_path / "rec.dat").write_text(AT2_HEAD + "NPTS= 30, DT= .01\n" + " .1" * 30 + "\n")
    path.write_text(SCENE.replace(*record("peer-at2")))
    assert load_scene(path).motion.record.dt == 0.01


def test_non_utf8_scene_file(tmp_path):
    path = tmp_path / "latin.toml"
    path.write_bytes(SCENE.replace("[soil]", "# sol d\xe9cap\xe9\n[soil]").encode("latin-1"))
    with pytest.raises(SceneError, match=r"latin.toml', line 1: byte 0xe9 is not UTF-8 text"):
        load_scene(path)


@pytest.mark.parametrize("make, message", [
    (lambda tmp: tmp, "is a directory"),
    (lambda tmp: tmp / "absent.toml", "does not exist"),
    (lambda tmp: "no-such-scene", "unknown scene 'no-such-scene'"),
])
def test_scene_spec_that_is_not_a_scene_file(tmp_path, make, message):
    with pytest.raises(SceneError, match=message):
        load_scene(make(tmp_path))


HOSTILE_VALUES = ["x", True, -1, 0, 0.0, 2.5, 1e308, float("nan"), float("inf"), 10 ** 30, [], [1, 2], [[1]],
                  [{"a": 1}], {}]


def _leaves(node, path=()):
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _leaves(v, path + (i,))
    if path:
        yield path


def _set(data, path, value):
    data = copy.deepcopy(data)
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


def test_every_value_replaced_by_a_hostile_one_loads_or_is_a_scene_error(tmp_path):
    """Each value (and each table or list) of three valid scenes (synthetic motion; a record; explicit
    Winkler moduli without a half-space) replaced by each of HOSTILE_VALUES: the scene loads (the value
    happens to be valid) or the loader raises SceneError, never another exception; a table where a
    value is expected is always refused."""
    (tmp_path / "rec.dat").write_text(TWO_COLUMN)
    base = tomllib.loads(SCENE)
    scenes = [base, _set(base, ("motion",), {"kind": "record", "file": "rec.dat", "scale": 2.0}),
              _set(base, ("soil",), {"winkler": {"kv": 1e8, "kh": 1e8, "cv": 1.0}})]
    refused = 0
    for data in scenes:
        scene_from_dict(data, base_dir=tmp_path)
        for path in set(_leaves(data)):
            for value in HOSTILE_VALUES + [{"a": 1}]:
                try:
                    scene_from_dict(_set(data, path, value), base_dir=tmp_path)
                except SceneError:
                    refused += 1
                else:
                    assert value != {"a": 1}, path
    assert refused > 0.8 * sum(len(set(_leaves(d))) for d in scenes) * (len(HOSTILE_VALUES) + 1)
