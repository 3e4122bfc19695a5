"""The ``handeye-jax.dataset/1`` format: the paper's file, round trips, validation, atomic save."""

from __future__ import annotations

import copy
import math
import os
import pickle
import stat
import tempfile
import tomllib
from pathlib import Path

import jax
import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import handeye_jax._core._atomic as atomic_mod
from handeye_jax import (
    Camera,
    Dataset,
    InputError,
    ParameterSpace,
    dataset_to_toml,
    load_dataset,
    save_dataset,
    update_dataset,
)
from handeye_jax.calibration import check_determined
from handeye_jax.data import FORMAT_V1, known_search_names
from handeye_jax.models import AffinePair, model_registry

PAPER = Path(__file__).resolve().parent.parent / "data" / "paper2023.toml"


@pytest.fixture(scope="module")
def paper() -> Dataset:
    return load_dataset(PAPER)


@pytest.fixture
def paper_doc() -> dict:
    return tomllib.loads(PAPER.read_text(encoding="utf-8"))


# -- the paper's data ---------------------------------------------------------------------------


def test_paper_file_values(paper: Dataset):
    assert paper.name == "paper2023"
    assert paper.source == PAPER
    assert paper.n_landmarks == 9
    assert paper.camera == Camera(617.7, 617.7, 316.5, 242.3)
    np.testing.assert_array_equal(paper.capture_position_mm, [320.0, -70.0, 290.0])
    assert (paper.tablet_ppi, paper.tablet_scale) == (267.0, 2.0)
    assert (paper.hand_angle_zero_deg, paper.hand_angle_sign) == (90.0, -1)
    assert type(paper.hand_angle_sign) is int
    assert paper.search == {}
    np.testing.assert_array_equal(paper.image_px[4], [338.0, 244.0])
    assert paper.depth_mm[4] == 169.2
    np.testing.assert_array_equal(paper.tablet_px[4], [720.0, 350.0])
    np.testing.assert_array_equal(paper.hand_xy_mm[4], [327.0, -17.0])
    np.testing.assert_array_equal(paper.touch_error_px[4], [-3.0, -1.0])
    np.testing.assert_array_equal(paper.hand_angle_deg, 22.5 * np.arange(9))
    assert paper.mm_per_tablet_px == pytest.approx(0.19026, abs=1e-5)
    assert paper.mm_per_tablet_px == 25.4 / 267.0 * 2.0
    for a in (paper.tablet_px, paper.image_px, paper.depth_mm, paper.hand_xy_mm):
        assert a.dtype == np.float64


def test_paper_tablet_grid_is_the_snake(paper: Dataset):
    xs, ys = (400.0, 720.0, 1040.0), (150.0, 350.0, 550.0)
    rows = [[(x, y) for x in xs] for y in ys]
    expected = rows[0] + rows[1][::-1] + rows[2]
    np.testing.assert_array_equal(paper.tablet_px, expected)


def test_paper_table2_rows(paper: Dataset):
    image = [(119, 105), (339, 108), (558, 109), (556, 246), (338, 244), (119, 242),
             (118, 379), (337, 379), (554, 381)]  # fmt: skip
    depth = [168.2, 168.6, 167.7, 167.5, 169.2, 168.7, 168.6, 170.2, 168.9]
    hand = [(289, 1), (347, 8), (403, 14), (395, -20), (327, -17), (257, -16),
            (249, -59), (305, -67), (363, -77)]  # fmt: skip
    touch = [(-3, 1), (-2, 3), (-1, 5), (-1, 4), (-3, -1), (3, 3), (2, 0), (-1, 3), (1, 2)]
    np.testing.assert_array_equal(paper.image_px, image)
    np.testing.assert_array_equal(paper.depth_mm, depth)
    np.testing.assert_array_equal(paper.hand_xy_mm, hand)
    np.testing.assert_array_equal(paper.touch_error_px, touch)


def test_paper_file_is_dataset_to_toml_output_plus_citation(paper: Dataset):
    text = PAPER.read_text(encoding="utf-8")
    generated = dataset_to_toml(paper)
    assert text.endswith(generated)
    assert all(line.startswith("#") for line in text[: -len(generated)].splitlines())


def test_observations_and_rig(paper: Dataset):
    with jax.enable_x64(True):
        obs = paper.observations()
    assert obs.centre_index == 4
    assert obs.n_landmarks == 9
    for a in (obs.image_px, obs.depth_mm, obs.tablet_mm, obs.hand_xy_mm, obs.hand_angle_deg,
              obs.touch_error_mm, obs.rig.fx_px, obs.rig.capture_position_mm):  # fmt: skip
        assert a.dtype == np.float64
    mm = paper.mm_per_tablet_px
    np.testing.assert_allclose(obs.tablet_mm, paper.tablet_px * mm, rtol=0, atol=0)
    np.testing.assert_allclose(obs.touch_error_mm, paper.touch_error_px * mm, rtol=0, atol=0)
    np.testing.assert_array_equal(obs.image_px, paper.image_px)
    rig = obs.rig
    assert float(rig.fx_px) == 617.7 and float(rig.cy_px) == 242.3
    assert (float(rig.angle_zero_deg), float(rig.angle_sign)) == (90.0, -1.0)
    np.testing.assert_array_equal(rig.capture_position_mm, [320.0, -70.0, 290.0])
    with jax.enable_x64(True):
        np.testing.assert_array_equal(obs.phi_deg(), 90.0 - 22.5 * np.arange(9))


def test_observations_are_float64_whatever_the_callers_setting(paper: Dataset):
    with jax.enable_x64(False):
        obs = paper.observations()
    assert obs.tablet_mm.dtype == np.float64
    assert obs.rig.fx_px.dtype == np.float64


# -- round trips ----------------------------------------------------------------------------------


def test_save_load_round_trip(paper: Dataset, tmp_path: Path):
    target = tmp_path / "copy.toml"
    save_dataset(paper, target)
    again = load_dataset(target)
    assert again == paper
    assert again.source == target
    assert os.listdir(tmp_path) == ["copy.toml"]


def test_round_trip_with_search_and_changes(paper: Dataset, tmp_path: Path):
    changed = paper.replace(
        name="with search",
        search={"xt": (100.0, 250.0), "X1": (-1.5, 2.0)},
        hand_angle_sign=1,
        depth_mm=paper.depth_mm + 0.1,
    )
    assert changed != paper
    assert paper.search == {}  # replace made a copy
    target = tmp_path / "s.toml"
    save_dataset(changed, target)
    again = load_dataset(target)
    assert again == changed
    assert again.search == {"xt": (100.0, 250.0), "X1": (-1.5, 2.0)}
    assert "[search]" in target.read_text(encoding="utf-8")


def test_dataset_to_toml_writes_floats_in_the_documented_order(paper: Dataset):
    text = dataset_to_toml(paper.replace(search={"xt": (100, 250)}))
    doc = tomllib.loads(text)
    assert list(doc) == ["format", "name", "camera", "capture", "tablet", "hand_angle",
                         "search", "landmarks"]  # fmt: skip
    assert list(doc["camera"]) == ["fx", "fy", "cx", "cy"]
    assert list(doc["landmarks"][0]) == ["tablet_px", "image_px", "depth", "hand_xy",
                                         "hand_angle", "touch_error_px"]  # fmt: skip
    assert doc["format"] == FORMAT_V1
    assert doc["hand_angle"]["sign"] == -1
    assert type(doc["tablet"]["ppi"]) is float
    assert all(type(v) is float for v in doc["search"]["xt"])
    assert all(type(v) is float for v in doc["landmarks"][0]["tablet_px"])
    assert "tablet_px = [400.0, 150.0]" in text  # pairs on one line


def within(lo: float, hi: float, exclude_min: bool = False):
    return st.floats(min_value=lo, max_value=hi, exclude_min=exclude_min)


px, mm, deg = within(-1e6, 1e6), within(-1e5, 1e5), within(-3600.0, 3600.0)  # every valid value
pair = st.tuples(px, px)


# Every image point within 80 deg of the optical axis: tan 80 deg = 5.67 > hypot(4, 4).
ray_tan = within(-4.0, 4.0)


@st.composite
def image_points(draw, camera: Camera, n: int) -> np.ndarray:
    """``n`` points the camera can see (clipped to the coordinate limit, which keeps them
    between the principal point and the drawn point, so within the angle)."""
    t = np.array(draw(st.lists(st.tuples(ray_tan, ray_tan), min_size=n, max_size=n)))
    uv = np.array([camera.cx_px, camera.cy_px]) + t * [camera.fx_px, camera.fy_px]
    return np.clip(uv, -1e6, 1e6)


@st.composite
def tablet_ppi_scale(draw) -> tuple[float, float]:
    """ppi and scale of a screen: one tablet px is 0.01 to 3 mm (a margin against rounding)."""
    ppi = draw(within(1, 1e5))
    lo, hi = max(0.01, 0.01 * ppi / 25.4), min(100.0, 3.0 * ppi / 25.4)
    return ppi, draw(within(lo * (1 + 1e-9), hi * (1 - 1e-9)))


@st.composite
def datasets(draw) -> Dataset:
    tablet = draw(st.lists(pair, min_size=1, max_size=12, unique=True))
    n = len(tablet)
    search_range = st.tuples(px, px).filter(lambda t: t[0] < t[1])
    camera = Camera(draw(within(1, 1e6)), draw(within(1, 1e6)), draw(px), draw(px))
    ppi, scale = draw(tablet_ppi_scale())
    return Dataset(
        name=draw(st.text(min_size=1, max_size=30).filter(lambda s: s.strip() != "")),
        camera=camera,
        capture_position_mm=np.array(draw(st.tuples(mm, mm, mm))),
        tablet_ppi=ppi,
        tablet_scale=scale,
        hand_angle_zero_deg=draw(deg),
        hand_angle_sign=draw(st.sampled_from([1, -1])),
        search=draw(
            st.dictionaries(st.sampled_from(sorted(known_search_names())), search_range, max_size=4)
        ),  # fmt: skip
        tablet_px=np.array(tablet),
        image_px=draw(image_points(camera, n)),
        depth_mm=np.array(draw(st.lists(within(0, 1e5, True), min_size=n, max_size=n))),
        hand_xy_mm=np.array(draw(st.lists(st.tuples(mm, mm), min_size=n, max_size=n))),
        hand_angle_deg=np.array(draw(st.lists(deg, min_size=n, max_size=n))),
        touch_error_px=np.array(draw(st.lists(pair, min_size=n, max_size=n))),
    )


def _unique_pairs(a: np.ndarray) -> bool:
    return len({(float(x), float(y)) for x, y in a}) == len(a)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ds=datasets())
def test_any_valid_dataset_round_trips_exactly(ds: Dataset):
    assume(_unique_pairs(ds.tablet_px))  # 0.0 and -0.0 are distinct to `unique`, not to us
    text = dataset_to_toml(ds)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "d.toml"
        path.write_text(text, encoding="utf-8")
        again = load_dataset(path)
    assert again == ds
    assert again.name == ds.name
    for name in ("tablet_px", "image_px", "depth_mm", "hand_xy_mm", "hand_angle_deg",
                 "touch_error_px", "capture_position_mm"):  # fmt: skip
        a, b = getattr(again, name), getattr(ds, name)
        assert a.tobytes() == b.tobytes()  # bit for bit, signed zeros included
    assert again.search == ds.search
    assert dataset_to_toml(again) == text


# -- validation -----------------------------------------------------------------------------------


def _set(doc: dict, keys: tuple, value) -> None:
    *head, last = keys
    for k in head:
        doc = doc[k]
    doc[last] = value


def _delete(doc: dict, keys: tuple) -> None:
    *head, last = keys
    for k in head:
        doc = doc[k]
    del doc[last]


def setting(*keys, value):
    return lambda doc: _set(doc, keys, value)


def deleting(*keys):
    return lambda doc: _delete(doc, keys)


def _dup_tablet(doc: dict) -> None:
    doc["landmarks"][7]["tablet_px"] = list(doc["landmarks"][1]["tablet_px"])


def _rename(doc: dict, keys: tuple, new: str) -> None:
    *head, last = keys
    for k in head:
        doc = doc[k]
    doc[new] = doc.pop(last)


# (id, mutation of the parsed paper document, expected field, expected message fragment)
DOC_CASES = [
    ("format-wrong", setting("format", value="handeye-jax.dataset/9"), "format", "expected"),
    ("format-missing", deleting("format"), "format", "missing"),
    ("name-empty", setting("name", value=""), "name", "non-empty string"),
    ("name-blank", setting("name", value="   "), "name", "non-empty string"),
    ("name-not-string", setting("name", value=3), "name", "got integer 3"),
    ("top-unknown", setting("colour", value="red"), "colour", "unknown key"),
    ("top-missing-table", deleting("camera"), "camera", "missing"),
    ("top-missing-landmarks", deleting("landmarks"), "landmarks", "missing"),
    ("table-not-table", setting("tablet", value=267), "tablet", "must be a table"),
    ("camera-unknown", lambda d: _rename(d, ("camera", "fy"), "fz"), "camera.fz", "unknown key"),
    ("camera-missing", deleting("camera", "cy"), "camera.cy", "missing"),
    (
        "capture-unknown",
        setting("capture", "hand_angle", value=0.0),
        "capture.hand_angle",
        "unknown key",
    ),
    ("capture-missing", deleting("capture", "hand_position"), "capture.hand_position", "missing"),
    ("tablet-missing", deleting("tablet", "scale"), "tablet.scale", "missing"),
    (
        "angle-unknown",
        setting("hand_angle", "offset", value=1.0),
        "hand_angle.offset",
        "unknown key",
    ),
    (
        "landmark-unknown",
        lambda d: _rename(d, ("landmarks", 3, "depth"), "depht"),
        "landmarks[3].depht",
        "did you mean 'depth'",
    ),
    (
        "landmark-missing",
        deleting("landmarks", 5, "hand_angle"),
        "landmarks[5].hand_angle",
        "missing",
    ),
    ("bool-not-number", setting("camera", "cx", value=True), "camera.cx", "got boolean true"),
    (
        "string-not-number",
        setting("landmarks", 2, "depth", value="168"),
        "landmarks[2].depth",
        "must be a number",
    ),
    (
        "bool-in-vector",
        setting("landmarks", 0, "hand_xy", value=[289.0, False]),
        "landmarks[0].hand_xy[1]",
        "must be a number",
    ),
    (
        "nan",
        setting("landmarks", 1, "hand_angle", value=math.nan),
        "landmarks[1].hand_angle",
        "must be finite (got nan)",
    ),
    (
        "inf-in-vector",
        setting("capture", "hand_position", value=[320.0, math.inf, 290.0]),
        "capture.hand_position[1]",
        "must be finite (got inf)",
    ),
    (
        "vector-too-short",
        setting("capture", "hand_position", value=[320.0, -70.0]),
        "capture.hand_position",
        "array of 3 numbers (got an array of 2)",
    ),
    (
        "pair-too-long",
        setting("landmarks", 0, "image_px", value=[1.0, 2.0, 3.0]),
        "landmarks[0].image_px",
        "array of 2 numbers",
    ),
    (
        "pair-not-array",
        setting("landmarks", 4, "touch_error_px", value=3.0),
        "landmarks[4].touch_error_px",
        "array of 2 numbers",
    ),
    ("fx-negative", setting("camera", "fx", value=-1.0), "camera.fx", "must be > 0 (got -1.0)"),
    ("fy-zero", setting("camera", "fy", value=0), "camera.fy", "must be > 0 (got 0)"),
    ("ppi-zero", setting("tablet", "ppi", value=0.0), "tablet.ppi", "must be > 0"),
    ("scale-negative", setting("tablet", "scale", value=-2), "tablet.scale", "must be > 0"),
    (
        "depth-zero",
        setting("landmarks", 3, "depth", value=0.0),
        "landmarks[3].depth",
        "must be > 0 (got 0.0)",
    ),
    ("sign-zero", setting("hand_angle", "sign", value=0), "hand_angle.sign", "must be 1 or -1"),
    ("sign-half", setting("hand_angle", "sign", value=-0.5), "hand_angle.sign", "1 or -1"),
    ("sign-two", setting("hand_angle", "sign", value=2), "hand_angle.sign", "1 or -1"),
    ("sign-bool", setting("hand_angle", "sign", value=True), "hand_angle.sign", "number"),
    ("search-not-table", setting("search", value=[1.0, 2.0]), "search", "must be a table"),
    (
        "search-unknown",
        setting("search", value={"xtt": [1.0, 2.0]}),
        "search.xtt",
        "unknown parameter name; did you mean 'xt'",
    ),
    ("search-not-pair", setting("search", value={"xt": 150.0}), "search.xt", "array of 2"),
    ("search-three", setting("search", value={"xt": [1.0, 2.0, 3.0]}), "search.xt", "array of 2"),
    (
        "search-reversed",
        setting("search", value={"xt": [250.0, 100.0]}),
        "search.xt",
        "lo < hi (got [250.0, 100.0])",
    ),
    ("search-empty-range", setting("search", value={"yp": [-20, -20]}), "search.yp", "lo < hi"),
    ("search-nan", setting("search", value={"xt": [math.nan, 1.0]}), "search.xt[0]", "finite"),
    ("search-string", setting("search", value={"xt": ["a", 1.0]}), "search.xt[0]", "number"),
    ("landmarks-empty", setting("landmarks", value=[]), "landmarks", "at least 1 landmark"),
    ("landmarks-not-tables", setting("landmarks", value=[1, 2]), "landmarks", "array of tables"),
    ("landmarks-duplicate", _dup_tablet, "landmarks[7].tablet_px", "duplicates landmarks[1]"),
    # Finite but beyond any rig: each would overflow or give NaN later in the fit.
    (
        "integer-beyond-float64",
        setting("landmarks", 0, "depth", value=10**400),
        "landmarks[0].depth",
        "must be finite (got an integer of 401 digits)",
    ),
    (
        "depth-huge",
        setting("landmarks", 0, "depth", value=1e308),
        "landmarks[0].depth",
        "must be at most 100000 in magnitude (got 1e+308)",
    ),
    (
        "image-px-huge",
        setting("landmarks", 2, "image_px", value=[1e308, 1.0]),
        "landmarks[2].image_px[0]",
        "at most 1e+06",
    ),
    (
        "hand-angle-huge",
        setting("landmarks", 1, "hand_angle", value=-4e3),
        "landmarks[1].hand_angle",
        "at most 3600",
    ),
    (
        "hand-xy-huge",
        setting("landmarks", 0, "hand_xy", value=[1e200, 0.0]),
        "landmarks[0].hand_xy[0]",
        "at most 100000",
    ),
    ("fx-tiny", setting("camera", "fx", value=1e-300), "camera.fx", "at least 1 px"),
    ("ppi-subnormal", setting("tablet", "ppi", value=5e-324), "tablet.ppi", "at least 1"),
    ("scale-tiny", setting("tablet", "scale", value=1e-3), "tablet.scale", "at least 0.01"),
    ("scale-huge", setting("tablet", "scale", value=1e308), "tablet.scale", "at most 100"),
    (
        "search-huge",
        setting("search", value={"xt": [-1e308, 1e308]}),
        "search.xt[0]",
        "at most 1e+06",
    ),
    # Nonsense a rig cannot produce (issue 16, section 3): each calibrated to F = 64 m.
    (
        "image-px-off-the-picture",
        setting("landmarks", 3, "image_px", value=[1e6, -1e6]),
        "landmarks[3].image_px",
        "is 90.0 deg off the camera's optical axis (at most 80 deg",
    ),
    (
        "tablet-px-of-no-screen",
        setting("tablet", value={"ppi": 1, "scale": 100}),
        "tablet",
        "one tablet px is 25.4 / ppi * scale = 2540 mm (ppi 1, scale 100)",
    ),
    (
        "tablet-px-too-fine",
        setting("tablet", value={"ppi": 1e5, "scale": 1}),
        "tablet",
        "a screen's pixel is 0.01 to 3 mm",
    ),
]


@pytest.mark.parametrize(
    ("mutate", "field", "fragment"),
    [pytest.param(m, f, frag, id=i) for i, m, f, frag in DOC_CASES],
)
def test_malformed_document(paper_doc, tmp_path: Path, mutate, field, fragment):
    doc = copy.deepcopy(paper_doc)
    mutate(doc)
    path = tmp_path / "bad-dataset.toml"
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    with pytest.raises(InputError) as info:
        load_dataset(path)
    err = info.value
    text = str(err)
    assert "bad-dataset.toml" in text
    assert field in text
    assert err.field == field
    assert fragment in err.message
    assert text == f"{path}: {field}: {err.message}"
    assert "\n" not in text


def _write(path: Path, data: bytes | None) -> None:
    if data is not None:
        path.write_bytes(data)


FILE_CASES = [
    ("missing-file", None, "cannot read file"),
    ("not-utf8", b'format = "\xff\xfe"\n', "cannot read file"),
    ("invalid-toml", b"format = \n", "not valid TOML: "),
    ("duplicate-key", b"name = 'again'\n" + PAPER.read_bytes(), "not valid TOML: "),
]


@pytest.mark.parametrize(("data", "fragment"), [pytest.param(d, f, id=i) for i, d, f in FILE_CASES])
def test_unreadable_or_unparsable_file(tmp_path: Path, data, fragment):
    path = tmp_path / "bad-file.toml"
    _write(path, data)
    with pytest.raises(InputError) as info:
        load_dataset(path)
    assert info.value.field == ""
    assert str(info.value).startswith(f"{path}: {fragment}")
    assert "\n" not in str(info.value)


def test_directory_is_unreadable(tmp_path: Path):
    path = tmp_path / "a-folder.toml"
    path.mkdir()
    with pytest.raises(InputError, match="cannot read file") as info:
        load_dataset(path)
    assert "a-folder.toml" in str(info.value)


def test_permission_denied(tmp_path: Path, monkeypatch):
    """Reading fails as it would for a file we may not read (simulated: tests run as root)."""
    path = tmp_path / "secret.toml"
    path.write_bytes(PAPER.read_bytes())

    real_open = os.open

    def denied(file, *args, **kwargs):
        if Path(file) == path:
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(os, "open", denied)
    with pytest.raises(InputError, match="cannot read file") as info:
        load_dataset(path)
    assert "secret.toml" in str(info.value) and "Permission denied" in str(info.value)


def test_lenient_where_the_format_allows(paper_doc, tmp_path: Path, paper: Dataset):
    """Integers for floats, a float ±1 sign, inline landmark tables and a BOM all load."""
    doc = copy.deepcopy(paper_doc)
    doc["capture"]["hand_position"] = [320, -70, 290]
    doc["tablet"] = {"ppi": 267, "scale": 2}
    doc["hand_angle"]["sign"] = -1.0
    doc["search"] = {}
    path = tmp_path / "ints.toml"
    path.write_bytes(b"\xef\xbb\xbf" + tomli_w.dumps(doc).encode("utf-8"))
    ds = load_dataset(path)
    assert ds == paper
    assert type(ds.hand_angle_sign) is int and type(ds.tablet_ppi) is float
    tables = PAPER.read_text(encoding="utf-8").split("[[landmarks]]")[0]
    inline = "landmarks = [\n"
    for m in paper_doc["landmarks"]:
        fields = ", ".join(f"{k} = {v!r}" for k, v in m.items())
        inline += f"  {{ {fields} }},\n"
    name_line = 'name = "paper2023"\n'
    path.write_text(tables.replace(name_line, name_line + inline + "]\n"), encoding="utf-8")
    assert load_dataset(path) == paper


def test_every_model_parameter_is_a_known_search_name():
    names = known_search_names()
    for cls in [*model_registry().values(), AffinePair]:
        assert set(cls.param_names) <= names


# -- enough landmarks -----------------------------------------------------------------------------


def _first(ds: Dataset, n: int) -> Dataset:
    return ds.replace(
        tablet_px=ds.tablet_px[:n], image_px=ds.image_px[:n], depth_mm=ds.depth_mm[:n],
        hand_xy_mm=ds.hand_xy_mm[:n], hand_angle_deg=ds.hand_angle_deg[:n],
        touch_error_px=ds.touch_error_px[:n],
    )  # fmt: skip


@pytest.mark.parametrize("n_free", [1, 8, 10, 12])
def test_the_landmark_rule_counts_free_parameters(n_free: int):
    """Each landmark gives four residuals: fewer than the free parameters is refused, as many
    is warned about plainly (the fit can match the data exactly)."""
    from handeye_jax import HTMModel

    template = HTMModel.nominal()
    names = HTMModel.param_names[:n_free]
    lo, hi = HTMModel.search_bounds()
    space = ParameterSpace(template, names, lo[:n_free], hi[:n_free])
    need = -(-n_free // 4)
    assert check_determined(need + 1, space, "stage 1", None) == []
    exact = check_determined(need, space, "stage 1", None)
    assert (exact != []) == (4 * need == n_free)
    if exact:
        assert "as many residuals" in exact[0].text and "touch more landmarks" in exact[0].text
    if need > 1:
        with pytest.raises(InputError) as info:
            check_determined(need - 1, space, "stage 1", "the/file.toml")
        assert str(info.value).startswith("the/file.toml: landmarks: stage 1 has ")
        assert f"at least {need} landmarks" in str(info.value)


def test_two_landmarks_for_twelve_parameters_are_refused_before_any_fit(paper: Dataset):
    """Three landmarks fit with a plain warning: tests/test_recalibration.py's
    ``test_a_fit_with_no_residuals_to_spare_warns`` runs that fit end to end."""
    from handeye_jax import Settings, calibrate

    with pytest.raises(InputError, match=r"landmarks: stage 1 has 12 free parameters but only 8"):
        calibrate(_first(paper, 2), Settings(population=40, generations=30, restarts=0))


def test_duplicate_landmarks_are_refused(paper: Dataset):
    from handeye_jax import Settings, calibrate

    tablet = paper.tablet_px.copy()
    tablet[6] = tablet[2]
    with pytest.raises(InputError, match=r"landmarks\[6\]\.tablet_px: duplicates landmarks\[2\]"):
        calibrate(paper.replace(tablet_px=tablet), Settings(population=40, generations=30))


def test_dataset_rejects_misshapen_arrays(paper: Dataset):
    with pytest.raises(ValueError, match="depth_mm"):
        paper.replace(depth_mm=paper.depth_mm[:5])
    with pytest.raises(ValueError, match="capture_position_mm"):
        paper.replace(capture_position_mm=np.zeros(2))


# -- atomic save ----------------------------------------------------------------------------------


def test_save_is_atomic_when_serialisation_fails(paper: Dataset, tmp_path: Path, monkeypatch):
    target = tmp_path / "d.toml"
    save_dataset(paper, target)
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise RuntimeError("serialiser broke")

    monkeypatch.setattr(tomli_w, "dumps", boom)
    with pytest.raises(RuntimeError, match="serialiser broke"):
        save_dataset(paper.replace(name="other"), target)
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["d.toml"]


def test_save_is_atomic_when_the_write_fails(paper: Dataset, tmp_path: Path, monkeypatch):
    target = tmp_path / "d.toml"
    save_dataset(paper, target)
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic_mod.os, "fsync", boom)
    with pytest.raises(InputError, match="d.toml: cannot write: .*No space left"):
        save_dataset(paper.replace(name="other"), target)
    monkeypatch.undo()
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["d.toml"]


def test_save_is_atomic_when_the_rename_fails(paper: Dataset, tmp_path: Path, monkeypatch):
    target = tmp_path / "d.toml"
    save_dataset(paper, target)
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic_mod.os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        save_dataset(paper.replace(name="other"), target)
    monkeypatch.undo()
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["d.toml"]


def test_save_refuses_an_invalid_dataset(paper: Dataset, tmp_path: Path):
    target = tmp_path / "d.toml"
    save_dataset(paper, target)
    before = target.read_bytes()
    bad = paper.replace(camera=Camera(-1.0, 617.7, 316.5, 242.3))
    with pytest.raises(InputError, match=r"d\.toml: camera\.fx: must be > 0 \(got -1\.0\)"):
        save_dataset(bad, target)
    with pytest.raises(InputError, match=r"landmarks\[0\]\.depth: must be finite"):
        save_dataset(paper.replace(depth_mm=np.full(9, np.nan)), target)
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["d.toml"]


def test_save_to_a_missing_folder(paper: Dataset, tmp_path: Path):
    with pytest.raises(InputError, match="cannot write"):
        save_dataset(paper, tmp_path / "nowhere" / "d.toml")
    assert os.listdir(tmp_path) == []


def test_saved_file_has_ordinary_permissions(paper: Dataset, tmp_path: Path):
    umask = os.umask(0o022)
    os.umask(umask)
    target = tmp_path / "d.toml"
    save_dataset(paper, target)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
    target.chmod(0o640)
    save_dataset(paper.replace(name="again"), target)
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert load_dataset(target).name == "again"


# -- updating a user's file in place -------------------------------------------------------------


def commented_paper_text() -> str:
    """The paper's file as a user might keep it: comments everywhere, integers, a long array."""
    text = PAPER.read_text(encoding="utf-8")
    text = "# my rig: SR300 on the UR5, measured by A. N. Other\n" + text
    text = text.replace("fx = 617.7", "fx = 617.7      # from the factory calibration")
    text = text.replace(
        "hand_position = [320.0, -70.0, 290.0]",
        "hand_position = [\n  320,  # x\n  -70,  # y\n  290,  # z\n]",
    )
    text = text.replace("\n[tablet]", "\n# the Surface Pro 7\n[tablet]")
    text = text.replace("depth = 168.2", "depth = 168.2  # re-read by hand")
    text = text.replace("touch_error_px = [-3.0, 1.0]", "touch_error_px = [-3.0, 1.0]  # first try")
    text = text.replace("hand_angle = 45.0\n", "hand_angle = 45.0\n# landmark 2 was retaken\n")
    text += "\n# end of file: keep this note\n"
    return text


def comments_of(text: str) -> list[str]:
    """Every comment (from ``#`` to the line's end) in a dataset's text, in order."""
    return [line[line.index("#") :] for line in text.splitlines() if "#" in line]


@pytest.fixture
def commented(tmp_path: Path) -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(commented_paper_text(), encoding="utf-8")
    return path


def test_update_keeps_every_comment_and_the_layout(commented: Path, paper: Dataset):
    before = commented.read_bytes()
    text = before.decode()
    assert len(comments_of(text)) >= 20 and load_dataset(commented) == paper
    rng = np.random.default_rng(3)
    touched = paper.replace(touch_error_px=np.round(rng.uniform(-5, 5, (9, 2)), 3))
    assert update_dataset(commented, touched) is not None  # what the tablet writes
    detected = touched.replace(image_px=paper.image_px + 0.125, depth_mm=paper.depth_mm - 0.5)
    assert update_dataset(commented, detected) is not None  # what detect writes
    after = commented.read_text(encoding="utf-8")
    assert comments_of(after) == comments_of(text)
    assert load_dataset(commented) == detected
    # Unchanged values keep their text: the integers, the multi-line array, the key order.
    assert "hand_position = [\n  320,  # x\n  -70,  # y\n  290,  # z\n]" in after
    assert after.splitlines()[:12] == text.splitlines()[:12]
    assert "depth = 167.7  # re-read by hand" in after  # 168.2 - 0.5, comment kept
    changed = [a for a, b in zip(text.splitlines(), after.splitlines(), strict=True) if a != b]
    assert len(changed) == 9 * 3  # image_px, depth, touch_error_px of each landmark
    backups = sorted(commented.parent.glob("rig.toml.*.bak"))
    assert len(backups) == 2  # every version kept
    assert backups[0].read_bytes() == before
    assert load_dataset(backups[1]) == touched


def test_update_with_the_same_values_writes_nothing(commented: Path, paper: Dataset):
    before = commented.read_bytes()
    assert update_dataset(commented, paper) is None
    assert update_dataset(commented, lambda ds: ds.replace(name="paper2023")) is None
    assert commented.read_bytes() == before
    assert os.listdir(commented.parent) == ["rig.toml"]


def test_update_from_a_function_of_the_file(commented: Path, paper: Dataset):
    # An edit made on disk after the caller loaded the dataset survives the update.
    edited = commented.read_text().replace("ppi = 267.0", "ppi = 270.0  # re-measured")
    commented.write_text(edited)
    assert update_dataset(commented, lambda ds: ds.replace(depth_mm=ds.depth_mm + 1.0))
    again = load_dataset(commented)
    assert again.tablet_ppi == 270.0 and np.allclose(again.depth_mm, paper.depth_mm + 1.0)
    assert "ppi = 270.0  # re-measured" in commented.read_text()


def test_update_changes_structure_too(commented: Path, paper: Dataset):
    new = _first(paper, 7).replace(name="trimmed", search={"xt": (100.0, 250.0)})
    assert update_dataset(commented, new)
    assert load_dataset(commented) == new
    assert "# my rig: SR300 on the UR5" in commented.read_text()
    more = paper.replace(search={})
    assert update_dataset(commented, more)
    assert load_dataset(commented) == more
    assert "# from the factory calibration" in commented.read_text()


def test_update_keeps_a_byte_order_mark_and_crlf(tmp_path: Path, paper: Dataset):
    path = tmp_path / "win.toml"
    path.write_bytes(b"\xef\xbb\xbf" + commented_paper_text().replace("\n", "\r\n").encode())
    new = paper.replace(touch_error_px=paper.touch_error_px + 1.0)
    assert update_dataset(path, new)
    raw = path.read_bytes()
    assert raw.startswith(b"\xef\xbb\xbf") and b"\n" not in raw.replace(b"\r\n", b"")
    assert load_dataset(path) == new


def test_a_failed_update_leaves_the_file_byte_identical(
    commented: Path, paper: Dataset, monkeypatch
):
    before = commented.read_bytes()
    with pytest.raises(InputError, match=r"rig\.toml: landmarks\[2\]\.depth: must be > 0"):
        update_dataset(commented, paper.replace(depth_mm=paper.depth_mm * [1, 1, -1, *[1] * 6]))
    with pytest.raises(InputError, match=r"landmarks\[0\]\.image_px\[1\]: must be finite"):
        update_dataset(commented, paper.replace(image_px=paper.image_px * [[1, np.nan]]))
    assert commented.read_bytes() == before
    assert os.listdir(commented.parent) == ["rig.toml"]

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic_mod.os, "fsync", full)
    with pytest.raises(
        InputError, match=r"rig\.toml\.[-T0-9.]+Z\.bak: cannot write: No space left"
    ):
        update_dataset(commented, paper.replace(name="other"))
    monkeypatch.undo()
    assert commented.read_bytes() == before
    assert os.listdir(commented.parent) == ["rig.toml"]  # no temporary file left

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic_mod.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        update_dataset(commented, paper.replace(name="other"), keep_backup=False)
    monkeypatch.undo()
    assert commented.read_bytes() == before
    assert os.listdir(commented.parent) == ["rig.toml"]


def test_an_update_whose_last_rename_fails_keeps_the_file_and_its_old_backup(
    commented: Path, paper: Dataset, monkeypatch
):
    assert update_dataset(commented, paper.replace(name="first"))  # makes a backup
    files = {p.name: p.read_bytes() for p in commented.parent.iterdir()}
    real = atomic_mod.os.replace

    def fails_on_the_dataset(src, dst):
        if Path(dst) == commented:
            raise OSError(5, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(atomic_mod.os, "replace", fails_on_the_dataset)
    with pytest.raises(InputError, match=r"rig\.toml: cannot write: Input/output error$"):
        update_dataset(commented, paper.replace(name="second"))
    monkeypatch.undo()
    assert {p.name: p.read_bytes() for p in commented.parent.iterdir()} == files


def test_update_refuses_a_file_that_is_not_a_valid_dataset(commented: Path, paper: Dataset):
    broken = commented.read_text().replace("scale = 2.0", "scale = -2.0")
    commented.write_text(broken)
    with pytest.raises(InputError, match=r"rig\.toml: tablet\.scale"):
        update_dataset(commented, paper)
    commented.write_text("not = [toml")
    with pytest.raises(InputError, match="not valid TOML"):
        update_dataset(commented, paper)
    with pytest.raises(InputError, match="cannot read"):
        update_dataset(commented.parent / "missing.toml", paper)
    assert commented.read_text() == "not = [toml"


# -- the error type -------------------------------------------------------------------------------


def test_input_error_format():
    assert str(InputError("a/b.toml", "camera.fx", "must be > 0")) == (
        "a/b.toml: camera.fx: must be > 0"
    )
    assert str(InputError(None, "camera.fx", "bad")) == "camera.fx: bad"
    assert str(InputError(Path("x.toml"), "", "bad")) == "x.toml: bad"
    assert str(InputError(None, "", "bad")) == "bad"
    assert str(InputError("f", "g", "two\nlines")) == "f: g: two lines"
    err = InputError(Path("x.toml"), "name", "bad")
    assert (err.path, err.field, err.message) == (Path("x.toml"), "name", "bad")
    assert isinstance(err, ValueError)
    again = pickle.loads(pickle.dumps(err))
    assert (again.path, again.field, again.message) == (err.path, err.field, err.message)
