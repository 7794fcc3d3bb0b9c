"""2D g2o pose graphs: poses, relative-pose edges, max-mixture edges, point landmarks.

Lines (whitespace-separated; blank lines and ``#`` comments are skipped)::

    VERTEX_SE2 id x y yaw
    VERTEX_XY id x y
    EDGE_SE2 a b x y yaw I11 I12 I13 I22 I23 I33
    EDGE_SE2_XY a b x y I11 I12 I22                  (pose a observes point b)
    EDGE_SE2_MIXTURE va vb n  EDGE_SE2 w a b x y yaw I11 I12 I13 I22 I23 I33  (n times)
    FIX id [id ...]

The information matrices are the upper triangle of a symmetric matrix, row
by row. ``EDGE_SE2_MIXTURE`` is the format of the max-mixture benchmark files
(Olson & Agarwal; agpratik/max-mixture): ``n`` weighted components, each a
relative-pose measurement that may join another pose pair than the header's
``va vb`` (multimodal data association); the weights are kept as written
(they need not sum to 1) and the null hypothesis is simply a component with a
tiny information.

Vertex ids of poses and points share one id space, as in g2o. Edges and
mixtures may come before the vertices they name; the reader checks every
reference at the end and names the edge's line. The writer puts vertices
first, then edges, landmark edges, mixtures and FIX, each in its own order:
a round trip keeps every list and its order, not the interleaving of an
original file. Numbers are written with Python's shortest exact repr, so a
round trip is bit-exact.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from semslam.errors import FormatError
from semslam.geometry import FloatArray
from semslam.io._rows import parse_number
from semslam.io._text import read_text, text_lines
from semslam.io.atomic import atomic_write_text

VERTEX_SE2 = "VERTEX_SE2"
VERTEX_XY = "VERTEX_XY"
EDGE_SE2 = "EDGE_SE2"
EDGE_SE2_XY = "EDGE_SE2_XY"
EDGE_SE2_MIXTURE = "EDGE_SE2_MIXTURE"
FIX = "FIX"

_TAGS = (VERTEX_SE2, VERTEX_XY, EDGE_SE2, EDGE_SE2_XY, EDGE_SE2_MIXTURE, FIX)
_SE2_INFO = ("I11", "I12", "I13", "I22", "I23", "I33")
_XY_INFO = ("I11", "I12", "I22")


# --------------------------------------------------------------------------- data


def _same_edge(x, y) -> bool:
    """Equal vertex pair, measurement and information (arrays compared exactly)."""
    return (
        (x.a, x.b) == (y.a, y.b)
        and np.array_equal(x.measurement, y.measurement)
        and np.array_equal(x.information, y.information)
    )


@dataclass(frozen=True, eq=False)
class Edge2D:
    """A relative-pose measurement ``aTb`` between poses ``a`` and ``b``.

    Attributes:
        a, b: vertex ids.
        measurement: (3,) ``(x, y, yaw)`` of b in a's frame; metres, radians (as written,
            not wrapped).
        information: (3, 3) symmetric positive-definite inverse covariance.
    """

    a: int
    b: int
    measurement: FloatArray
    information: FloatArray

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Edge2D) and _same_edge(self, other)

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class PointEdge2D:
    """Pose ``a`` observes point ``b`` at ``measurement`` (2,) in its own frame, metres,
    with (2, 2) information."""

    a: int
    b: int
    measurement: FloatArray
    information: FloatArray

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PointEdge2D) and _same_edge(self, other)

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class MixtureComponent:
    """One hypothesis of a mixture edge: a prior ``weight`` (> 0) and its measurement."""

    weight: float
    edge: Edge2D


@dataclass(frozen=True)
class MixtureEdge2D:
    """A max-mixture edge: header pose pair ``(a, b)`` and its weighted components."""

    a: int
    b: int
    components: tuple[MixtureComponent, ...]


@dataclass
class PoseGraph2D:
    """A 2D pose graph as read from or written to g2o.

    Attributes:
        vertices: pose id -> (3,) ``(x, y, yaw)`` (the initial guess, or the solution).
        edges: plain relative-pose edges, in file order.
        mixtures: max-mixture edges, in file order.
        points: point-landmark id -> (2,) ``(x, y)``.
        point_edges: pose-to-point observations, in file order.
        fixed: ids named by FIX lines, in file order.
    """

    vertices: dict[int, FloatArray] = field(default_factory=dict)
    edges: list[Edge2D] = field(default_factory=list)
    mixtures: list[MixtureEdge2D] = field(default_factory=list)
    points: dict[int, FloatArray] = field(default_factory=dict)
    point_edges: list[PointEdge2D] = field(default_factory=list)
    fixed: list[int] = field(default_factory=list)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PoseGraph2D):
            return NotImplemented
        return (
            _same_arrays(self.vertices, other.vertices)
            and _same_arrays(self.points, other.points)
            and self.edges == other.edges
            and self.mixtures == other.mixtures
            and self.point_edges == other.point_edges
            and self.fixed == other.fixed
        )

    __hash__ = None  # type: ignore[assignment]


def _same_arrays(a: dict[int, FloatArray], b: dict[int, FloatArray]) -> bool:
    return list(a) == list(b) and all(np.array_equal(a[k], b[k]) for k in a)


# --------------------------------------------------------------------------- helpers


def information_from_upper(values: ArrayLike) -> FloatArray:
    """The symmetric matrix whose upper triangle, row by row, is ``values``
    (6 values -> 3x3, 3 values -> 2x2)."""
    v = np.asarray(values, dtype=float)
    n = {6: 3, 3: 2}.get(v.size)
    if n is None:
        raise ValueError(f"expected 3 or 6 upper-triangle values, got {v.size}")
    m = np.zeros((n, n))
    rows, cols = _upper_indices(n)
    m[rows, cols] = v
    m[cols, rows] = v
    return m


def information_upper(information: FloatArray) -> FloatArray:
    """The upper triangle of a symmetric matrix, row by row."""
    m = np.asarray(information, dtype=float)
    return m[_upper_indices(m.shape[0])]


@functools.cache
def _upper_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n)``, made once per size (a graph has thousands of edges)."""
    return np.triu_indices(n)


MAX_INFORMATION = 1e15
"""Largest information entry (or eigenvalue) accepted: a standard deviation of 3e-8."""

MIN_INFORMATION = 1e-12
"""Smallest information eigenvalue accepted (a standard deviation of 1e6 m or rad)."""

MAX_CONDITION = 1e12
"""Largest condition number of an information matrix a solver can use reliably."""

MAX_VALUE = 1e6
"""Largest ``|x|``, ``|y|`` (m) or ``|yaw|`` (rad) of a vertex or a measurement: beyond
1000 km a file is broken (the solvers would lose every digit of it)."""


def information_problem(m: FloatArray) -> str | None:
    """Why an information matrix cannot be solved with, or None when it can: not positive
    definite, an entry above :data:`MAX_INFORMATION`, an eigenvalue below
    :data:`MIN_INFORMATION`, or a condition number above :data:`MAX_CONDITION`
    (gtsam stops on such matrices with an indeterminate system)."""
    eigenvalues = np.linalg.eigvalsh(m)
    if not eigenvalues[0] > 0:
        return "is not positive definite"
    largest_entry = float(np.max(np.abs(m)))
    if largest_entry > MAX_INFORMATION:
        return f"has an entry of {largest_entry:g} (at most {MAX_INFORMATION:g})"
    if eigenvalues[0] < MIN_INFORMATION:
        return f"has an eigenvalue of {eigenvalues[0]:g} (at least {MIN_INFORMATION:g})"
    condition = float(eigenvalues[-1] / eigenvalues[0])
    if condition > MAX_CONDITION:
        return f"is ill-conditioned (condition number {condition:.3g} > {MAX_CONDITION:g})"
    return None


class _InformationChecks:
    """The information matrices of a file, checked together (:func:`information_problem`
    over one stacked eigen-decomposition per size: 14 ms for the 11,858 edges of a
    `garage` map's graph, where one call per edge took most of the parse)."""

    def __init__(self) -> None:
        self.matrices: dict[int, list[FloatArray]] = {2: [], 3: []}
        self.places: dict[int, list[tuple[int, str, str]]] = {2: [], 3: []}
        self.count = 0

    def add(self, info: FloatArray, where: str, what: str) -> None:
        n = info.shape[0]
        self.matrices[n].append(info)
        self.places[n].append((self.count, where, what))
        self.count += 1

    def raise_first(self) -> None:
        """Raises FormatError for the first matrix in the file with a problem."""
        bad: list[tuple[int, str, str, FloatArray]] = []
        for n, matrices in self.matrices.items():
            if not matrices:
                continue
            stack = np.array(matrices)
            eigenvalues = np.linalg.eigvalsh(stack)
            low, high = eigenvalues[:, 0], eigenvalues[:, -1]
            with np.errstate(divide="ignore", invalid="ignore"):
                fine = ((low > 0) & (np.abs(stack).max(axis=(1, 2)) <= MAX_INFORMATION)
                        & (low >= MIN_INFORMATION) & (high / low <= MAX_CONDITION))
            for i in np.flatnonzero(~fine)[:1]:
                bad.append((*self.places[n][i], stack[i]))
        if bad:
            _, where, what, info = min(bad, key=lambda b: b[0])
            raise FormatError(f"{where}: {what} information matrix {information_problem(info)}")


class _Tokens:
    """The tokens of one line, consumed left to right with checked conversions."""

    def __init__(self, tokens: list[str], where: str, checks: _InformationChecks) -> None:
        self.tokens = tokens
        self.pos = 0
        self.where = where
        self.checks = checks

    def fail(self, what: str) -> FormatError:
        return FormatError(f"{self.where}: {what}")

    def _next(self, name: str) -> str:
        if self.pos >= len(self.tokens):  # callers check counts first; kept as a guard
            raise self.fail(f"missing {name}")
        tok = self.tokens[self.pos]
        self.pos += 1
        return tok

    def integer(self, name: str) -> int:
        tok = self._next(name)
        try:
            value = int(tok)
        except ValueError:
            raise self.fail(f"{name} is not an integer id ({tok!r})") from None
        if not 0 <= value < 2**63:  # gtsam keys and numpy int64
            raise self.fail(f"{name} must be in 0 .. 2^63 - 1, got {value}")
        return value

    def number(self, name: str) -> float:
        return parse_number(self._next(name), self.where, name, FormatError)

    def numbers(self, names: tuple[str, ...]) -> FloatArray:
        return np.array([self.number(n) for n in names])

    def values(self, names: tuple[str, ...]) -> FloatArray:
        """Numbers of a pose, point or measurement, each within :data:`MAX_VALUE`."""
        return np.array(
            [parse_number(self._next(n), self.where, n, FormatError, MAX_VALUE) for n in names]
        )

    def information(self, names: tuple[str, ...], what: str) -> FloatArray:
        """The information matrix of the next numbers; checked with the file's others at the
        end (:class:`_InformationChecks`)."""
        info = information_from_upper(self.numbers(names))
        self.checks.add(info, self.where, what)
        return info


def _expect(tokens: list[str], count: int, where: str, form: str) -> None:
    if len(tokens) != count:
        raise FormatError(f"{where}: expected {count} fields ({form}), got {len(tokens)}")


_FORMS = {
    VERTEX_SE2: "VERTEX_SE2 id x y yaw",
    VERTEX_XY: "VERTEX_XY id x y",
    EDGE_SE2: "EDGE_SE2 a b x y yaw I11 I12 I13 I22 I23 I33",
    EDGE_SE2_XY: "EDGE_SE2_XY a b x y I11 I12 I22",
}


def _read_edge(t: _Tokens, what: str = "edge") -> Edge2D:
    a = t.integer("a")
    b = t.integer("b")
    if a == b:
        raise t.fail(f"{what} joins vertex {a} to itself")
    measurement = t.values(("x", "y", "yaw"))
    return Edge2D(a, b, measurement, t.information(_SE2_INFO, what))


# --------------------------------------------------------------------------- reading


def parse_g2o(text: str, name: str = "<g2o>") -> PoseGraph2D:
    """Parse g2o text; ``name`` is used in messages (see :func:`read_g2o`)."""
    graph = PoseGraph2D()
    # (line, description, pose ids, point ids) of every reference, checked at the end
    refs: list[tuple[str, str, tuple[int, ...], tuple[int, ...]]] = []
    checks = _InformationChecks()
    for lineno, line in enumerate(text_lines(text), start=1):
        body = line.split("#", 1)[0].strip()
        if not body:
            continue
        where = f"{name} line {lineno}"
        tokens = body.split()
        tag = tokens[0]
        if tag not in _TAGS:
            raise FormatError(f"{where}: unknown tag {tag!r} (expected one of: {', '.join(_TAGS)})")
        t = _Tokens(tokens, where, checks)
        t.pos = 1
        if tag in _FORMS:
            _expect(tokens, len(_FORMS[tag].split()), where, _FORMS[tag])
        if tag == VERTEX_SE2:
            vid = t.integer("id")
            value = t.values(("x", "y", "yaw"))
            if vid in graph.vertices or vid in graph.points:
                raise t.fail(f"vertex {vid} defined twice")
            graph.vertices[vid] = value
        elif tag == VERTEX_XY:
            vid = t.integer("id")
            value = t.values(("x", "y"))
            if vid in graph.vertices or vid in graph.points:
                raise t.fail(f"vertex {vid} defined twice")
            graph.points[vid] = value
        elif tag == EDGE_SE2:
            edge = _read_edge(t)
            graph.edges.append(edge)
            refs.append((where, "edge", (edge.a, edge.b), ()))
        elif tag == EDGE_SE2_XY:
            a = t.integer("a")
            b = t.integer("b")
            measurement = t.values(("x", "y"))
            info = t.information(_XY_INFO, "edge")
            graph.point_edges.append(PointEdge2D(a, b, measurement, info))
            refs.append((where, "edge", (a,), (b,)))
        elif tag == EDGE_SE2_MIXTURE:
            graph.mixtures.append(_read_mixture(t, tokens, where))
            mix = graph.mixtures[-1]
            ids = (mix.a, mix.b) + tuple(i for c in mix.components for i in (c.edge.a, c.edge.b))
            refs.append((where, "mixture edge", ids, ()))
        else:  # FIX
            if len(tokens) < 2:
                raise t.fail("expected FIX id [id ...]")
            ids = tuple(t.integer("id") for _ in tokens[1:])
            graph.fixed.extend(ids)
            refs.append((where, "FIX", ids, ()))
    checks.raise_first()
    for where, what, pose_ids, point_ids in refs:
        for vid in pose_ids:
            if vid not in graph.vertices:
                raise FormatError(f"{where}: {what} names pose vertex {vid}, which is not defined")
        for vid in point_ids:
            if vid not in graph.points:
                raise FormatError(f"{where}: {what} names point vertex {vid}, which is not defined")
    return graph


def _read_mixture(t: _Tokens, tokens: list[str], where: str) -> MixtureEdge2D:
    form = "EDGE_SE2_MIXTURE va vb n, then n times EDGE_SE2 w a b x y yaw I11 I12 I13 I22 I23 I33"
    if len(tokens) < 4:
        raise FormatError(f"{where}: expected at least 4 fields ({form}), got {len(tokens)}")
    va = t.integer("va")
    vb = t.integer("vb")
    n = t.integer("n")
    if n < 1:
        raise t.fail("a mixture edge needs at least 1 component, got 0")
    per = 1 + len(_FORMS[EDGE_SE2].split())  # tag + w + a b x y yaw + 6 information
    _expect(tokens, 4 + n * per, where, f"{form}; n = {n}")
    components = []
    for k in range(1, n + 1):
        tag = t._next("component tag")
        if tag != EDGE_SE2:
            raise t.fail(f"component {k}: expected tag {EDGE_SE2}, got {tag!r}")
        weight = t.number(f"component {k} weight")
        if weight <= 0:
            raise t.fail(f"component {k}: weight must be > 0, got {weight!r}")
        components.append(MixtureComponent(weight, _read_edge(t, f"component {k}")))
    return MixtureEdge2D(va, vb, tuple(components))


def read_g2o(path: str | os.PathLike[str]) -> PoseGraph2D:
    """Read a 2D g2o pose graph (see the module doc for the lines understood).

    Raises:
        FormatError: missing or unreadable file, unknown tag, wrong field count, a
            non-number, NaN or infinity, a coordinate or angle beyond :data:`MAX_VALUE`, a
            negative or non-integer id, a vertex defined twice, an edge joining a vertex
            to itself or naming an undefined vertex, a non-positive weight, an
            information matrix that is not positive definite or is ill-conditioned (see
            :func:`information_problem`); the one-line message is ``"<file> line N: ..."``.
            A file without any ``VERTEX_SE2`` line (empty, only comments or only points)
            is refused: ``"<file>: no VERTEX_SE2 lines"``.
    """
    name = os.fspath(path)
    graph = parse_g2o(read_text(path, FormatError), name)
    if not graph.vertices:
        raise FormatError(f"{name}: no VERTEX_SE2 lines (a pose graph needs at least one pose)")
    return graph


# --------------------------------------------------------------------------- writing


def _num(v: float) -> str:
    return repr(float(v))


def _edge_fields(e: Edge2D) -> list[str]:
    return [
        str(e.a),
        str(e.b),
        *(_num(v) for v in e.measurement),
        *(_num(v) for v in information_upper(e.information)),
    ]


def format_g2o(graph: PoseGraph2D, name: str = "<g2o>") -> str:
    """The g2o text of ``graph``; refuses what :func:`parse_g2o` would refuse."""
    lines = []
    for vid, v in graph.vertices.items():
        lines.append(" ".join([VERTEX_SE2, str(vid), *(_num(x) for x in v)]))
    for vid, p in graph.points.items():
        lines.append(" ".join([VERTEX_XY, str(vid), *(_num(x) for x in p)]))
    for e in graph.edges:
        lines.append(" ".join([EDGE_SE2, *_edge_fields(e)]))
    for pe in graph.point_edges:
        lines.append(
            " ".join(
                [
                    EDGE_SE2_XY,
                    str(pe.a),
                    str(pe.b),
                    *(_num(x) for x in pe.measurement),
                    *(_num(x) for x in information_upper(pe.information)),
                ]
            )
        )
    for m in graph.mixtures:
        parts = [EDGE_SE2_MIXTURE, str(m.a), str(m.b), str(len(m.components))]
        for c in m.components:
            parts += [EDGE_SE2, _num(c.weight), *_edge_fields(c.edge)]
        lines.append(" ".join(parts))
    if graph.fixed:
        lines.append(" ".join([FIX, *(str(i) for i in graph.fixed)]))
    text = "\n".join(lines) + "\n"
    try:
        parse_g2o(text, "output")  # refuse to write what would not read back
    except FormatError as exc:
        raise FormatError(
            f"{name}: refusing to write a graph that would not read back ({exc})"
        ) from None
    return text


def write_g2o(path: str | os.PathLike[str], graph: PoseGraph2D) -> None:
    """Write ``graph`` as g2o text, atomically.

    Raises:
        FormatError: the graph would not read back (NaN, undefined vertex, an information
            matrix that is not positive definite...); the target is left unchanged.
    """
    name = os.fspath(path)
    _check_shapes(graph, name)
    atomic_write_text(path, format_g2o(graph, name))


def _check_shapes(graph: PoseGraph2D, name: str) -> None:
    def bad(what: str) -> FormatError:
        return FormatError(f"{name}: {what}")

    for vid, v in graph.vertices.items():
        if np.shape(v) != (3,):
            raise bad(f"pose vertex {vid} must be (x, y, yaw), got shape {np.shape(v)}")
    for vid, p in graph.points.items():
        if np.shape(p) != (2,):
            raise bad(f"point vertex {vid} must be (x, y), got shape {np.shape(p)}")
    edges = list(graph.edges) + [c.edge for m in graph.mixtures for c in m.components]
    for e in edges:
        if np.shape(e.measurement) != (3,) or np.shape(e.information) != (3, 3):
            raise bad(f"edge {e.a}-{e.b} needs a (3,) measurement and (3, 3) information")
        if not np.array_equal(e.information, np.transpose(e.information)):
            raise bad(f"edge {e.a}-{e.b} information is not symmetric")
    for pe in graph.point_edges:
        if np.shape(pe.measurement) != (2,) or np.shape(pe.information) != (2, 2):
            raise bad(f"edge {pe.a}-{pe.b} needs a (2,) measurement and (2, 2) information")
        if not np.array_equal(pe.information, np.transpose(pe.information)):
            raise bad(f"edge {pe.a}-{pe.b} information is not symmetric")
    for m in graph.mixtures:
        if not m.components:
            raise bad(f"mixture edge {m.a}-{m.b} has no components")
    for v in list(graph.vertices.values()) + list(graph.points.values()):
        if not np.all(np.isfinite(v)):
            raise bad("a vertex has a NaN or infinite coordinate")
    if any(not math.isfinite(c.weight) for m in graph.mixtures for c in m.components):
        raise bad("a mixture weight is NaN or infinite")
