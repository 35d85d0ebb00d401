"""Sewing patterns: panels (closed 2D outlines in metres), seams and grain lines.

A `Panel` is a closed loop of named `Edge`s, counter-clockwise seen from the outside of
the garment, each a straight line or a cubic Bézier curve. A `Seam` joins one edge of a
panel to one edge of another (or the same) panel; `reverse` says that the start of edge
`a` meets the end of edge `b`; `ease` is how much longer one edge may be than the other
(sewing eases the difference in). The grain line is the fabric's warp (first material axis,
u) in panel coordinates. `placement` tells the dressing step where the panel goes on the
body (`part`: torso / arm / leg / legs, `side`: front / back, `limb`: L / R).

Patterns save to and load from JSON, and export to SVG for a look or a print.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tryon.errors import InputFileError, TryonError
from tryon.io.atomic import atomic_write


SEAM_EASE = 0.03  # a seam's edges may differ by 3 % (+1 mm) unless the draft says otherwise


class PatternError(TryonError):
    """A sewing pattern is malformed (open outline, unknown edge, mismatched seam)."""


@dataclass
class Edge:
    """A panel edge: 'line' through 2 points or 'bezier' through 4 (start, two controls, end)."""

    name: str
    points: np.ndarray
    kind: str = "line"

    def __post_init__(self) -> None:
        try:
            self.points = np.asarray(self.points, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise PatternError(f"edge {self.name!r}: points must be numbers ({exc})") from None
        need = {"line": 2, "bezier": 4}.get(self.kind)
        if need is None:
            raise PatternError(f"edge {self.name!r}: kind must be 'line' or 'bezier', got {self.kind!r}")
        if self.points.shape != (need, 2) or not np.isfinite(self.points).all():
            raise PatternError(f"edge {self.name!r}: a {self.kind} needs {need} finite 2D points, got {self.points.tolist()}")

    @property
    def start(self) -> np.ndarray:
        return self.points[0]

    @property
    def end(self) -> np.ndarray:
        return self.points[-1]

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)[:, None]
        p = self.points
        if self.kind == "line":
            return (1 - t) * p[0] + t * p[1]
        return (1 - t) ** 3 * p[0] + 3 * (1 - t) ** 2 * t * p[1] + 3 * (1 - t) * t**2 * p[2] + t**3 * p[3]

    def polyline(self, n: int = 200) -> np.ndarray:
        return self.evaluate(np.linspace(0.0, 1.0, n + 1))

    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.polyline(), axis=0), axis=1).sum())

    def sample(self, segments: int) -> np.ndarray:
        """`segments + 1` points at equal arc length from start to end."""
        dense = self.polyline(max(400, 20 * segments))
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        targets = np.linspace(0.0, s[-1], segments + 1)
        return np.stack([np.interp(targets, s, dense[:, 0]), np.interp(targets, s, dense[:, 1])], 1)

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "points": self.points.round(6).tolist()}


@dataclass
class Panel:
    name: str
    edges: list[Edge]
    grain: tuple[float, float] = (0.0, 1.0)
    placement: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.edges) < 3:
            raise PatternError(f"panel {self.name!r}: needs at least 3 edges, got {len(self.edges)}")
        names = [e.name for e in self.edges]
        if len(set(names)) != len(names):
            raise PatternError(f"panel {self.name!r}: edge names repeat: {names}")
        for a, b in zip(self.edges, self.edges[1:] + self.edges[:1]):
            if np.linalg.norm(a.end - b.start) > 1e-6:
                raise PatternError(
                    f"panel {self.name!r}: outline is open between edge {a.name!r} (ends at {a.end.round(4).tolist()}) "
                    f"and {b.name!r} (starts at {b.start.round(4).tolist()})"
                )
        g = np.asarray(self.grain, dtype=np.float64)
        if g.shape != (2,) or not np.isfinite(g).all() or np.linalg.norm(g) < 1e-9:
            raise PatternError(f"panel {self.name!r}: grain must be a non-zero 2D direction, got {self.grain}")
        self.grain = tuple(float(x) for x in g / np.linalg.norm(g))
        if self.signed_area() <= 0:
            raise PatternError(f"panel {self.name!r}: outline must run counter-clockwise and enclose an area")

    def edge(self, name: str) -> Edge:
        for e in self.edges:
            if e.name == name:
                return e
        raise PatternError(f"panel {self.name!r} has no edge {name!r}; its edges: {[e.name for e in self.edges]}")

    def outline(self, n: int = 60) -> np.ndarray:
        return np.concatenate([e.polyline(n)[:-1] for e in self.edges])

    def signed_area(self) -> float:
        p = self.outline()
        return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        p = self.outline()
        return p.min(0), p.max(0)

    def to_dict(self) -> dict:
        return {"name": self.name, "grain": list(self.grain), "placement": self.placement, "edges": [e.to_dict() for e in self.edges]}


@dataclass
class Seam:
    a: tuple[str, str]  # (panel, edge)
    b: tuple[str, str]
    reverse: bool = False
    ease: float = SEAM_EASE  # the edges may differ by this fraction of the longer (+1 mm): sewing takes it up

    def to_dict(self) -> dict:
        d = {"a": list(self.a), "b": list(self.b), "reverse": self.reverse}
        if self.ease != SEAM_EASE:
            d["ease"] = self.ease
        return d


@dataclass
class Pattern:
    """A garment's panels and seams. `meta` records the draft, size, measurements and ease."""

    name: str
    panels: list[Panel]
    seams: list[Seam]
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = [p.name for p in self.panels]
        if len(set(names)) != len(names):
            raise PatternError(f"pattern {self.name!r}: panel names repeat: {names}")
        used = set()
        for s in self.seams:
            for side in (s.a, s.b):
                self.panel(side[0]).edge(side[1])
                if side in used:
                    raise PatternError(f"pattern {self.name!r}: edge {side} is sewn twice")
                used.add(side)
            if not 0.0 <= s.ease < 0.5:
                raise PatternError(f"pattern {self.name!r}: seam {s.a} - {s.b} has ease {s.ease}; use 0 to 0.5")
            la, lb = self.seam_edges(s)[0].length(), self.seam_edges(s)[1].length()
            if abs(la - lb) > s.ease * max(la, lb) + 1e-3:
                raise PatternError(
                    f"pattern {self.name!r}: seam {s.a} - {s.b} joins edges of different lengths "
                    f"({la * 100:.1f} cm vs {lb * 100:.1f} cm)"
                )

    def panel(self, name: str) -> Panel:
        for p in self.panels:
            if p.name == name:
                return p
        raise PatternError(f"pattern {self.name!r} has no panel {name!r}; panels: {[p.name for p in self.panels]}")

    def seam_edges(self, s: Seam) -> tuple[Edge, Edge]:
        return self.panel(s.a[0]).edge(s.a[1]), self.panel(s.b[0]).edge(s.b[1])

    def area(self) -> float:
        return sum(p.signed_area() for p in self.panels)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {"format": "tryon-pattern-1", "name": self.name, "meta": self.meta,
                "panels": [p.to_dict() for p in self.panels], "seams": [s.to_dict() for s in self.seams]}

    @classmethod
    def from_dict(cls, d: dict, source: str = "pattern") -> "Pattern":
        try:
            panels = [
                Panel(p["name"], [Edge(e["name"], e["points"], e.get("kind", "line")) for e in p["edges"]],
                      tuple(p.get("grain", (0.0, 1.0))), dict(p.get("placement", {})))
                for p in d["panels"]
            ]
            seams = [Seam(tuple(s["a"]), tuple(s["b"]), bool(s.get("reverse", False)), float(s.get("ease", SEAM_EASE)))
                     for s in d["seams"]]
            return cls(d["name"], panels, seams, dict(d.get("meta", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise PatternError(f"{source}: not a tryon pattern ({exc!r}); expected name, panels[edges], seams") from exc

    def save(self, path: str | Path) -> Path:
        with atomic_write(path) as fh:
            json.dump(self.to_dict(), fh, indent=1)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "Pattern":
        try:
            d = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise InputFileError(f"{path}: cannot read the pattern ({exc})") from exc
        return cls.from_dict(d, str(path))

    def to_svg(self, path: str | Path, gap: float = 0.05) -> Path:
        """Panels side by side at 1:1 scale (mm units), edges labelled, grain arrows."""
        parts, x0, height = [], 0.0, 0.0
        for p in self.panels:
            lo, hi = p.bounds()
            height = max(height, hi[1] - lo[1])
        for p in self.panels:
            lo, hi = p.bounds()
            off = np.array([x0 - lo[0], -lo[1]])

            def tr(q: np.ndarray) -> str:
                q = (q + off) * 1000.0
                return f"{q[0]:.1f},{(height * 1000.0 - q[1]):.1f}"

            outline = " ".join(tr(q) for q in p.outline(40))
            parts.append(f'<polygon points="{outline}" fill="#dde6f2" stroke="#223" stroke-width="1"/>')
            for e in p.edges:
                mid = e.evaluate(np.array([0.5]))[0]
                x, y = tr(mid).split(",")
                parts.append(f'<text x="{x}" y="{y}" font-size="14" fill="#a33">{e.name}</text>')
            c = 0.5 * (lo + hi)
            g = np.asarray(p.grain) * 0.25 * (hi[1] - lo[1])
            a, b = tr(c - g), tr(c + g)
            parts.append(f'<line x1="{a.split(",")[0]}" y1="{a.split(",")[1]}" x2="{b.split(",")[0]}" y2="{b.split(",")[1]}" '
                         f'stroke="#555" stroke-width="2" marker-end="url(#arrow)"/>')
            cx, cy = tr(c).split(",")
            parts.append(f'<text x="{cx}" y="{cy}" font-size="22" text-anchor="middle">{p.name}</text>')
            x0 += hi[0] - lo[0] + gap
        width_mm, height_mm = x0 * 1000.0, height * 1000.0 + 20
        svg = (
            f'<svg xmlns="http://www.w3.org/2000/svg" width="{width_mm:.0f}mm" height="{height_mm:.0f}mm" '
            f'viewBox="0 0 {width_mm:.0f} {height_mm:.0f}">\n'
            '<defs><marker id="arrow" markerWidth="10" markerHeight="10" refX="5" refY="3" orient="auto">'
            '<path d="M0,0 L0,6 L9,3 z" fill="#555"/></marker></defs>\n'
            f'<title>{self.name}</title>\n' + "\n".join(parts) + "\n</svg>\n"
        )
        with atomic_write(path) as fh:
            fh.write(svg)
        return Path(path)


def plot_pattern(pattern: Pattern, path: str | Path, gap: float = 0.06) -> Path:
    """PNG of the panels side by side at true relative scale, with edge names and grain."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 5), dpi=100)
    x0 = 0.0
    for p in pattern.panels:
        lo, hi = p.bounds()
        off = np.array([x0 - lo[0], -lo[1]])
        q = p.outline(40) + off
        ax.fill(q[:, 0], q[:, 1], color="#dde6f2", ec="#223", lw=1.2)
        for e in p.edges:
            mid = e.evaluate(np.array([0.5]))[0] + off
            ax.annotate(e.name, mid, fontsize=7, color="#a33", ha="center")
        c = 0.5 * (lo + hi) + off
        g = np.asarray(p.grain) * 0.2 * (hi[1] - lo[1])
        ax.annotate("", c + g, c - g, arrowprops=dict(arrowstyle="->", color="#555"))
        ax.text(c[0], c[1] - 0.04, p.name, ha="center", fontsize=10)
        x0 += hi[0] - lo[0] + gap
    ax.set_aspect("equal")
    ax.set_title(f"{pattern.name} {pattern.meta.get('size') or ''} (m)")
    fig.tight_layout()
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png")
    plt.close(fig)
    return Path(path)
