"""Unit strings of imported sources: the factor to SI and the SI unit the record states.

A mapping's ``units`` (``hil import --unit CHANNEL=UNIT``) names the unit the *source* values are in.
Values in a unit that is not the SI unit of its dimension are multiplied by the factor to SI (after the
mapping's ``scale``) and the record states the SI unit: ``mm`` -> ``m`` (x 0.001), ``deg`` -> ``rad``
(x pi/180), ``rpm`` -> ``rad/s``, ``ms`` -> ``s``, ``N.mm`` -> ``N.m``, ``lbf`` -> ``N``.

Unit strings are parsed with pint (an extra: ``pip install 'hil-certify[units]'``), except the SI
strings the suite itself writes into its records (:data:`SI_STRINGS`, e.g. ``rad``, ``N.m``, ``m/s``,
``1``), which need no conversion and no pint. ``.`` between two unit names means a product
(``N.m``, the records' spelling). An unknown unit, or one with an offset (``degC``), is refused with
one line naming it.
"""

from __future__ import annotations

import functools
import logging
import re
from typing import Any

from hil.record.hdf5 import RecordError

logger = logging.getLogger(__name__)

__all__ = ["PINT_MISSING", "SI_STRINGS", "to_si"]

#: unit strings already in SI as the suite writes them: recorded as given, factor 1, no pint needed
SI_STRINGS = frozenset({"", "1", "s", "m", "rad", "kg", "N", "N.m", "m/s", "rad/s", "m/s^2", "rad/s^2", "J", "W",
                        "V", "A", "N/m", "N.s/m", "N.m/rad", "N.m.s/rad", "kg.m²", "kg.m^2", "N, N.m", "Hz"})

PINT_MISSING = "unit {unit!r} needs the 'pint' package: pip install 'hil-certify[units]'"

#: pint base-unit expression (``f"{units:~}"`` of ``to_base_units()``) -> the suite's SI spelling
_PREFERRED = {
    "": "1", "s": "s", "m": "m", "rad": "rad", "kg": "kg", "A": "A", "K": "K", "1 / s": "Hz",
    "m / s": "m/s", "rad / s": "rad/s", "m / s ** 2": "m/s^2", "rad / s ** 2": "rad/s^2",
    "kg * m / s ** 2": "N", "kg * m ** 2 / s ** 2": "N.m", "kg * m ** 2 / rad / s ** 2": "N.m/rad",
    "kg * m ** 2 / A / s ** 3": "V", "kg / s ** 2": "N/m", "kg / s": "N.s/m", "kg * m ** 2 / s": "N.m.s",
    "kg * m ** 2 / rad / s": "N.m.s/rad", "kg * m ** 2": "kg.m^2", "kg * m ** 2 / s ** 3": "W",
    "count": "1",
}

#: spellings pint reads otherwise (``Nm`` would be a unit of its own): newton-metres
_ALIASES = {"Nm": "N.m", "Nmm": "N.mm", "mNm": "mN.m", "kNm": "kN.m"}

_PRODUCT_DOT = re.compile(r"(?<=[A-Za-zµΩ°²³)])\.(?=[A-Za-zµΩ°(])")


@functools.cache
def _registry() -> Any:
    import pint  # extra [units]: only when a unit string is not one of SI_STRINGS

    return pint.UnitRegistry()


@functools.cache
def to_si(unit: str) -> tuple[float, str]:
    """``(factor, si_unit)``: a value in ``unit`` times ``factor`` is in ``si_unit`` (the string the
    record states). Raises :class:`RecordError` (one line) for an unknown or offset unit, or when the
    string needs pint and pint is not installed."""
    text = unit.strip()
    text = _ALIASES.get(text, text)
    if text in SI_STRINGS:
        return 1.0, text
    try:
        ureg = _registry()
    except ImportError:
        raise RecordError(PINT_MISSING.format(unit=unit)) from None
    import pint

    expr = _PRODUCT_DOT.sub("*", text).replace("²", "**2").replace("³", "**3").replace("^", "**")
    try:
        q = ureg.Quantity(1.0, expr)
        base = q.to_base_units()
    except pint.errors.OffsetUnitCalculusError:
        raise RecordError(f"unit {unit!r} has an offset (like degC); give the values in an absolute unit (K)") \
            from None
    except (pint.errors.UndefinedUnitError, pint.errors.DefinitionSyntaxError, AttributeError, TypeError,
            ValueError, SyntaxError, AssertionError) as exc:
        why = " ".join(str(exc).split())[:120]
        raise RecordError(f"unknown unit {unit!r}" + (f" ({why})" if why else "")) from None
    if not q._ok_for_muldiv():  # an offset unit (degC, degF) alone converts without error: refuse it too
        raise RecordError(f"unit {unit!r} has an offset (like degC); give the values in an absolute unit (K)")
    key = f"{base.units:~}"
    si = _PREFERRED.get(key, key.replace(" * ", ".").replace(" ** ", "^").replace(" / ", "/"))
    factor = float(base.magnitude)
    logger.debug("unit %r -> x %.17g %s", unit, factor, si)
    return factor, si
