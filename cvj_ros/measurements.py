"""Measured lever-hinge coupling torques shipped in the package (Davidbaev et al. 2023, tables 4.2-4.11).

The data are the book's printed numbers (``cvj_ros/data/davidbaev2023/``, its README gives
columns, units and operating conditions). :func:`load_table` reads one table in SI units
(N m, rad); :func:`average_mismatches` lists the rows whose printed "average value" is not the
mean of the row's six ordinates rounded to the printed decimals.
"""
from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from decimal import Decimal
from importlib import resources

import numpy as np
from numpy.typing import NDArray

from cvj_ros.physics.ordinates import OrdinateHarmonics, ordinate_harmonics

__all__ = ['TABLE_NAMES', 'MeasuredTable', 'load_table', 'load_tables', 'average_mismatches',
           'printed_average_ok']

FloatArray = NDArray[np.float64]
TABLE_NAMES = tuple(f'4.{k}' for k in range(2, 12))
_UNIT = 10.0            # the book's torque unit, 10 N m
_DIR = ('data', 'davidbaev2023')


@dataclass(frozen=True)
class MeasuredTable:
    """One measured table: ``ordinates`` (cycles, 12) in N m at ``angle_rad`` (rad) of the
    shaft ``angle_of``; ``printed_average`` (12,) N m and the ``printed_text`` it came from;
    ``stiffness`` the bushings' reduced torsional stiffness of the rubber grade (N m/rad, the
    book's fig. 4.7), None where the book gives none."""

    name: str
    torque: str                 # 'M1' or 'M2'
    shaft: str                  # 'driving' or 'driven'
    angle_of: str
    rubber: str
    rubber_printed: str
    stiffness: float | None
    angle_rad: FloatArray
    ordinates: FloatArray
    printed_average: FloatArray
    printed_text: tuple[str, ...]
    ordinate_text: tuple[tuple[str, ...], ...]   # (rows, cycles), as printed

    @property
    def cycles(self) -> int:
        return int(self.ordinates.shape[0])

    def harmonics(self) -> OrdinateHarmonics:
        """Harmonics (eqs. 4.2-4.3) of the cycle-averaged ordinates (the coefficients are
        linear in the ordinates, so these are the means of the per-cycle coefficients)."""
        return ordinate_harmonics(self.ordinates.mean(axis=0))

    def cycle_harmonics(self) -> list[OrdinateHarmonics]:
        """Harmonics of every measured revolution on its own."""
        return [ordinate_harmonics(row) for row in self.ordinates]


def _read(name: str) -> str:
    return resources.files('cvj_ros').joinpath(*_DIR, name).read_text(encoding='utf-8')


def _index() -> dict[str, dict[str, str]]:
    return {r['table']: r for r in csv.DictReader(io.StringIO(_read('tables.csv')))}


def load_table(name: str) -> MeasuredTable:
    """Table ``name`` ('4.2' .. '4.11'). Raises KeyError naming the known tables."""
    index = _index()
    if name not in index:
        raise KeyError(f'table {name!r}: not shipped; tables: {", ".join(TABLE_NAMES)}')
    meta = index[name]
    rows = list(csv.DictReader(io.StringIO(_read(f'table_4_{int(name.split(".")[1]):02d}.csv'))))
    cols = [c for c in rows[0] if c.startswith('cycle_')]
    text = tuple(tuple(r[c] for c in cols) for r in rows)
    ords = np.array([[float(x) * _UNIT for x in row] for row in text]).T
    stiff = meta['stiffness_nm_rad'].strip()
    return MeasuredTable(
        name=name, torque=meta['torque'], shaft=meta['shaft'], angle_of=meta['angle_of'],
        rubber=meta['rubber'], rubber_printed=meta['rubber_printed'],
        stiffness=float(stiff) if stiff else None,
        angle_rad=np.radians([float(r['angle_deg']) for r in rows]),
        ordinates=ords, printed_average=np.array([float(r['average']) * _UNIT for r in rows]),
        printed_text=tuple(r['average'] for r in rows), ordinate_text=text)


def load_tables() -> dict[str, MeasuredTable]:
    """Every shipped table by name, in the book's order."""
    return {n: load_table(n) for n in TABLE_NAMES}


def printed_average_ok(ordinates: tuple[str, ...], printed: str) -> bool:
    """Whether ``printed`` is the mean of the decimal ``ordinates`` rounded to its own
    number of decimals (exact decimal arithmetic: |mean - printed| <= half a unit of the
    printed last digit)."""
    vals = [Decimal(x) for x in ordinates]
    mean = sum(vals, Decimal(0)) / len(vals)
    p = Decimal(printed)
    half = Decimal(1).scaleb(p.as_tuple().exponent) / 2
    return abs(mean - p) <= half


def average_mismatches(table: MeasuredTable) -> tuple[int, ...]:
    """Row numbers (1..12) whose printed average does not follow from the row's ordinates."""
    return tuple(i + 1 for i, (ords, pr) in enumerate(zip(table.ordinate_text, table.printed_text))
                 if not printed_average_ok(ords, pr))
