"""Polynomials in the unknowns with separated coefficients.

:class:`Atom` is an unknown or one of its derivatives (or a general term,
:mod:`pgdcli.problem.general`); a ``Monomial`` is a sorted tuple of atoms; a
:class:`Polynomial` maps monomials to their :class:`~pgdcli.problem.separable.Separable`
coefficients, the unknown-free part being the monomial ``()``.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Iterator, Mapping, NamedTuple

from .separable import Separable, as_separable
from .terms import join_signed, term_text

__all__ = ["Atom", "Monomial", "Polynomial", "make_monomial", "format_monomial", "as_polynomial"]


class Atom(NamedTuple):
    """An unknown or one of its derivatives.

    Attributes
    ----------
    unknown : str
    coordinate : str or None
        None for the value itself, else the coordinate of the derivative (the
        time coordinate for ``der(u)``).
    order : int
        0 for the value, 1 or 2 for derivatives.
    """

    unknown: str
    coordinate: str | None = None
    order: int = 0

    def text(self, time: str | None = None) -> str:
        """Text as written in an equation; ``der(u)`` if the coordinate is ``time``."""
        if self.order == 0:
            return self.unknown
        if self.order == 1 and self.coordinate == time:
            return f"der({self.unknown})"
        if self.order == 1:
            return f"der({self.unknown}, {self.coordinate})"
        return f"der({self.unknown}, {self.coordinate}, {self.order})"

    def __str__(self) -> str:
        return self.text()


#: Sorted tuple of atoms; ``()`` is the unknown-free part.
Monomial = tuple  # tuple[Atom, ...]


def _atom_key(atom: Atom) -> tuple:
    # None and str do not compare: the value itself sorts before its derivatives
    return (atom.unknown, atom.coordinate or "", atom.order)


def make_monomial(*atoms: Atom) -> Monomial:
    """The canonical (sorted) monomial of some atoms."""
    return tuple(sorted(atoms, key=_atom_key))


def format_monomial(monomial: Monomial, time: str | None = None) -> str:
    """Text of a monomial, e.g. ``u*v``, ``der(u)*u``, ``u**2``; '1' for ``()``."""
    counts: dict[Atom, int] = {}
    for atom in monomial:
        counts[atom] = counts.get(atom, 0) + 1
    parts = [atom.text(time) + (f"**{n}" if n > 1 else "") for atom, n in counts.items()]
    return "*".join(parts) or "1"


def _monomial_sort_key(monomial: Monomial) -> tuple:
    return (len(monomial), [_atom_key(atom) for atom in monomial])


@dataclass(frozen=True, eq=False)
class Polynomial:
    """A polynomial in unknowns (and their derivatives) with separated coefficients.

    Attributes
    ----------
    terms : Mapping[Monomial, Separable]
        Read-only mapping without zero coefficients, ordered by degree.
        ``terms[()]`` is the unknown-free part, ``terms[(Atom('u'),)]`` the
        coefficient of u, ``terms[(Atom('u', 't', 1),)]`` that of der(u).
    """

    terms: Mapping[Monomial, Separable]

    def __post_init__(self) -> None:
        merged: dict[Monomial, Separable] = {}
        for monomial, sep in dict(self.terms).items():
            key = make_monomial(*monomial)
            merged[key] = merged[key] + sep if key in merged else sep
        ordered = {m: merged[m] for m in sorted(merged, key=_monomial_sort_key) if not merged[m].is_zero}
        object.__setattr__(self, "terms", MappingProxyType(ordered))

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def constant(cls, value: float) -> Polynomial:
        return cls({(): Separable.constant(value)})

    @classmethod
    def from_separable(cls, sep: Separable) -> Polynomial:
        return cls({(): sep})

    @classmethod
    def atom(cls, atom: Atom) -> Polynomial:
        return cls({(atom,): Separable.constant(1.0)})

    # -- mapping interface -----------------------------------------------------------------
    def items(self):
        return self.terms.items()

    def keys(self):
        return self.terms.keys()

    def values(self):
        return self.terms.values()

    def get(self, monomial: Monomial, default: Separable | None = None) -> Separable | None:
        return self.terms.get(monomial, default)

    def __getitem__(self, monomial: Monomial) -> Separable:
        return self.terms[monomial]

    def __contains__(self, monomial: object) -> bool:
        return monomial in self.terms

    def __iter__(self) -> Iterator[Monomial]:
        return iter(self.terms)

    def coefficient(self, monomial: Monomial = ()) -> Separable:
        """Coefficient of a monomial, zero if absent (``()``: the unknown-free part)."""
        return self.terms.get(make_monomial(*monomial), Separable())

    # -- properties ------------------------------------------------------------------------
    @property
    def degree(self) -> int:
        """Largest number of atoms in a monomial (0 for an unknown-free polynomial)."""
        return max((len(m) for m in self.terms), default=0)

    @property
    def atoms(self) -> frozenset[Atom]:
        return frozenset(atom for monomial in self.terms for atom in monomial)

    @property
    def unknowns(self) -> frozenset[str]:
        return frozenset(atom.unknown for atom in self.atoms)

    @property
    def is_zero(self) -> bool:
        return not self.terms

    @property
    def term_count(self) -> int:
        """Total number of separated terms over all coefficients."""
        return sum(len(sep.terms) + len(sep.joints) for sep in self.terms.values())

    # -- arithmetic ------------------------------------------------------------------------
    def __add__(self, other: Polynomial | Separable | float) -> Polynomial:
        other = as_polynomial(other)
        if other is None:
            return NotImplemented
        merged = dict(self.terms)
        for monomial, sep in other.items():
            merged[monomial] = merged[monomial] + sep if monomial in merged else sep
        return Polynomial(merged)

    __radd__ = __add__

    def __neg__(self) -> Polynomial:
        return Polynomial({m: -sep for m, sep in self.items()})

    def __sub__(self, other: Polynomial | Separable | float) -> Polynomial:
        other = as_polynomial(other)
        if other is None:
            return NotImplemented
        return self + (-other)

    def __rsub__(self, other: Separable | float) -> Polynomial:
        other = as_polynomial(other)
        if other is None:
            return NotImplemented
        return other + (-self)

    def __mul__(self, other: Polynomial | Separable | float) -> Polynomial:
        other = as_polynomial(other)
        if other is None:
            return NotImplemented
        product: dict[Monomial, Separable] = {}
        for m1, s1 in self.items():
            for m2, s2 in other.items():
                key = make_monomial(*m1, *m2)
                sep = s1 * s2
                product[key] = product[key] + sep if key in product else sep
        return Polynomial(product)

    __rmul__ = __mul__

    # -- comparison, text ------------------------------------------------------------------
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Polynomial):
            return NotImplemented
        return dict(self.terms) == dict(other.terms)

    def __hash__(self) -> int:
        return hash(frozenset(self.terms.items()))

    def __repr__(self) -> str:
        return f"Polynomial({dict(self.terms)!r})"

    def __str__(self) -> str:
        pieces: list[tuple[bool, str]] = []
        for monomial, sep in self.items():
            if not monomial:
                pieces += [(t.coef < 0, term_text(t, signed=False)) for t in sep.terms]
                pieces += [(j.term.coef < 0, str(j.scaled(-1.0) if j.term.coef < 0 else j)) for j in sep.joints]
            elif len(sep.terms) == 1 and not sep.joints:
                term = sep.terms[0]
                coef_text = term_text(term, signed=False)
                text = format_monomial(monomial) if coef_text == "1" else f"{coef_text}*{format_monomial(monomial)}"
                pieces.append((term.coef < 0, text))
            else:
                pieces.append((False, f"({sep})*{format_monomial(monomial)}"))
        return join_signed(pieces)


def as_polynomial(value: object) -> Polynomial | None:
    if isinstance(value, Polynomial):
        return value
    sep = as_separable(value)
    return None if sep is None else Polynomial.from_separable(sep)

