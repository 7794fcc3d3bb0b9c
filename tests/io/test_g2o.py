import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semslam.errors import FormatError
from semslam.io.g2o import (
    Edge2D,
    MixtureComponent,
    MixtureEdge2D,
    PointEdge2D,
    PoseGraph2D,
    format_g2o,
    information_from_upper,
    information_upper,
    parse_g2o,
    read_g2o,
    write_g2o,
)

# Lines as the benchmark files write them (agpratik/max-mixture; multimodal variant).
OUTLIER_LINE = (
    "EDGE_SE2_MIXTURE 5 9 2 EDGE_SE2 1 5 9 0.0339432 0.0324387 -3.1274 44.7214 0 0 44.7214 0 "
    "44.7214 EDGE_SE2 0.01 5 9 0.0339432 0.0324387 -3.1274 4.47214e-10 0.0 0.0 4.47214e-10 0.0 "
    "4.47214e-10"
)
MULTIMODAL_LINE = (
    "EDGE_SE2_MIXTURE 5 827 3 EDGE_SE2 1 5 827 0.0339432 0.0324387 -3.1274  44.7214 0 0 44.7214 "
    "0 44.7214 EDGE_SE2 1 5 9 0.0339432 0.0324387 -3.1274  44.7214 0 0 44.7214 0 44.7214 "
    "EDGE_SE2 1e-07 5 827 0.0339432 0.0324387 -3.1274  4.47214e-06 0 0 4.47214e-06 0 "
    "4.47214e-06 "
)


def _vertices(ids):
    return "".join(f"VERTEX_SE2 {i} {i}.0 0 0\n" for i in ids)


def test_reads_benchmark_mixture_lines():
    text = _vertices([5, 9, 827]) + OUTLIER_LINE + "\n" + MULTIMODAL_LINE + "\nFIX 5\n"
    g = parse_g2o(text, "bench.g2o")
    assert list(g.vertices) == [5, 9, 827] and g.fixed == [5]
    out, mm = g.mixtures
    assert (out.a, out.b, len(out.components)) == (5, 9, 2)
    assert out.components[1].weight == 0.01
    np.testing.assert_allclose(out.components[1].edge.information, np.eye(3) * 4.47214e-10)
    np.testing.assert_allclose(out.components[0].edge.measurement, [0.0339432, 0.0324387, -3.1274])
    assert [(c.edge.a, c.edge.b) for c in mm.components] == [(5, 827), (5, 9), (5, 827)]
    assert [c.weight for c in mm.components] == [1.0, 1.0, 1e-07]


def test_information_upper_triangle_order():
    info = information_from_upper([1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(info, [[1, 2, 3], [2, 4, 5], [3, 5, 6]])
    np.testing.assert_array_equal(information_upper(info), [1, 2, 3, 4, 5, 6])
    np.testing.assert_array_equal(information_from_upper([1, 2, 3]), [[1, 2], [2, 3]])


def test_landmarks_comments_and_blank_lines():
    text = (
        "# a comment\n\nVERTEX_SE2 0 0 0 0\nVERTEX_XY 7 1.5 -2\n"
        "EDGE_SE2_XY 0 7 1.5 -2 10 0 10  # trailing comment\n"
    )
    g = parse_g2o(text)
    np.testing.assert_array_equal(g.points[7], [1.5, -2.0])
    (pe,) = g.point_edges
    assert (pe.a, pe.b) == (0, 7)
    np.testing.assert_array_equal(pe.information, np.eye(2) * 10)


# --------------------------------------------------------------------------- round trip

finite = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)


@st.composite
def spd(draw, n):
    a = np.array(draw(st.lists(finite, min_size=n * n, max_size=n * n))).reshape(n, n) * 1e-2
    m = a @ a.T + np.eye(n) * draw(st.floats(1e-3, 1e3))
    return 0.5 * (m + m.T)


@st.composite
def graphs(draw):
    n = draw(st.integers(2, 6))
    ids = draw(st.lists(st.integers(0, 10_000), min_size=n, max_size=n, unique=True))
    g = PoseGraph2D()
    for i in ids:
        g.vertices[i] = np.array(draw(st.lists(finite, min_size=3, max_size=3)))
    free = [i for i in range(10_001, 10_010)]
    for i in free[: draw(st.integers(0, 3))]:
        g.points[i] = np.array(draw(st.lists(finite, min_size=2, max_size=2)))

    def edge():
        a, b = draw(st.lists(st.sampled_from(ids), min_size=2, max_size=2, unique=True))
        return Edge2D(a, b, np.array(draw(st.lists(finite, min_size=3, max_size=3))), draw(spd(3)))

    g.edges = [edge() for _ in range(draw(st.integers(0, 4)))]
    for _ in range(draw(st.integers(0, 3))):
        comps = tuple(
            MixtureComponent(draw(st.floats(1e-12, 10)), edge())
            for _ in range(draw(st.integers(1, 4)))
        )
        g.mixtures.append(MixtureEdge2D(comps[0].edge.a, comps[0].edge.b, comps))
    for p in g.points:
        g.point_edges.append(
            PointEdge2D(
                draw(st.sampled_from(ids)),
                p,
                np.array(draw(st.lists(finite, min_size=2, max_size=2))),
                draw(spd(2)),
            )
        )
    g.fixed = draw(st.lists(st.sampled_from(ids), max_size=2))
    return g


@settings(max_examples=60, deadline=None)
@given(graphs())
def test_text_round_trip_is_exact(g):
    assert parse_g2o(format_g2o(g)) == g


def test_file_round_trip(tmp_path):
    g = parse_g2o(_vertices([5, 9, 827]) + OUTLIER_LINE + "\n" + MULTIMODAL_LINE + "\nFIX 5\n")
    path = tmp_path / "sub" / "graph.g2o"
    write_g2o(path, g)
    assert read_g2o(path) == g
    assert [p.name for p in path.parent.iterdir()] == ["graph.g2o"]  # no temporary left


def test_writer_refuses_what_would_not_read_back(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text("old\n")
    g = PoseGraph2D(vertices={0: np.array([0.0, math.nan, 0.0]), 1: np.zeros(3)})
    with pytest.raises(FormatError, match="g.g2o"):
        write_g2o(path, g)
    g = PoseGraph2D(
        vertices={0: np.zeros(3)}, edges=[Edge2D(0, 1, np.zeros(3), np.eye(3))]
    )  # vertex 1 missing
    with pytest.raises(FormatError, match="vertex 1"):
        write_g2o(path, g)
    g = PoseGraph2D(
        vertices={0: np.zeros(3), 1: np.zeros(3)}, edges=[Edge2D(0, 1, np.zeros(3), -np.eye(3))]
    )
    with pytest.raises(FormatError, match="positive definite"):
        write_g2o(path, g)
    assert path.read_text() == "old\n"


# --------------------------------------------------------------------------- broken files

V01 = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
INFO = "1 0 0 1 0 1"


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", 1, "unknown tag 'VERTEX_SE3:QUAT'"),
        ("VERTEX_SE2 0 0 0\n", 1, "expected 5 fields"),
        ("VERTEX_SE2 0 0 abc 0\n", 1, "y is not a number ('abc')"),
        ("VERTEX_SE2 0 0 nan 0\n", 1, "y is NaN"),
        ("VERTEX_SE2 0 0 inf 0\n", 1, "y is infinite"),
        ("VERTEX_SE2 0 1e300 0 0\n", 1, "x 1e+300 is out of range (|x| <= 1e+06)"),
        ("VERTEX_XY 0 0 -2e6\n", 1, "y -2e+06 is out of range"),
        (V01 + f"EDGE_SE2 0 1 1 0 1e9 {INFO}\n", 3, "yaw 1e+09 is out of range"),
        (V01 + f"EDGE_SE2_MIXTURE 0 1 1 EDGE_SE2 1 0 1 1e300 0 0 {INFO}\n", 3, "x 1e+300"),
        ("VERTEX_SE2 1.0 0 0 0\n", 1, "id is not an integer"),
        ("VERTEX_SE2 -1 0 0 0\n", 1, "id must be in 0 .. 2^63 - 1"),
        ("VERTEX_SE2 9223372036854775808 0 0 0\n", 1, "id must be in 0 .. 2^63 - 1"),
        (V01 + "VERTEX_XY 1 0 0\n", 3, "vertex 1 defined twice"),
        (V01 + f"EDGE_SE2 0 2 1 0 0 {INFO}\n", 3, "names pose vertex 2"),
        (V01 + f"EDGE_SE2 0 0 1 0 0 {INFO}\n", 3, "joins vertex 0 to itself"),
        (V01 + "EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n", 3, "not positive definite"),
        (V01 + "EDGE_SE2 0 1 1 0 0 1 2 0 1 0 1\n", 3, "not positive definite"),
        (V01 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", 3, "expected 12 fields"),
        (V01 + f"EDGE_SE2_MIXTURE 0 1 2 EDGE_SE2 1 0 1 1 0 0 {INFO}\n", 3, "n = 2"),
        (V01 + f"EDGE_SE2_MIXTURE 0 1 1 EDGE_SE3 1 0 1 1 0 0 {INFO}\n", 3, "component 1"),
        (V01 + f"EDGE_SE2_MIXTURE 0 1 1 EDGE_SE2 0 0 1 1 0 0 {INFO}\n", 3, "weight must be > 0"),
        (V01 + f"EDGE_SE2_MIXTURE 0 1 1 EDGE_SE2 1 0 5 1 0 0 {INFO}\n", 3, "pose vertex 5"),
        (V01 + "EDGE_SE2_MIXTURE 0 1 0\n", 3, "at least 1 component"),
        (V01 + "EDGE_SE2_XY 0 1 1 0 1 0 1\n", 3, "names point vertex 1"),
        (V01 + "FIX\n", 3, "expected FIX id"),
        (V01 + "FIX 0 7\n", 3, "FIX names pose vertex 7"),
    ],
)
def test_broken_lines_name_file_and_line(text, line, message):
    with pytest.raises(FormatError) as info:
        parse_g2o(text, "broken.g2o")
    msg = str(info.value)
    assert msg.startswith(f"broken.g2o line {line}: "), msg
    assert message in msg
    assert "\n" not in msg


def test_edge_before_its_vertices_is_fine_and_missing_file_is_a_format_error(tmp_path):
    g = parse_g2o(f"EDGE_SE2 0 1 1 0 0 {INFO}\n" + V01)
    assert len(g.edges) == 1
    with pytest.raises(FormatError, match="file not found"):
        read_g2o(tmp_path / "missing.g2o")


def test_a_line_ends_only_at_a_newline():
    """Form feeds and U+2028 inside a comment do not end the line (g2o reads lines as
    getline does); a commented-out FIX stays commented out."""
    g = parse_g2o("VERTEX_SE2 0 0 0 0 # a\u2028FIX 0\r\nVERTEX_SE2 1 1 0 0 # b\x0cc\n", "f.g2o")
    assert sorted(g.vertices) == [0, 1] and g.fixed == []
