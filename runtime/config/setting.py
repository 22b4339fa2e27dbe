"""One setting of the run's configuration, written once on its field: its help, the values
it may take, and the flag that gives it on the command line.

A section (:mod:`.sections`) declares each field with :func:`setting`. From that one
declaration come the options of ``ctrlunit start`` and the single roles
(runtime/cli/options.py), the check of its value (``RunConfig.validate``), the help above
each key of the run file ``ctrlunit config`` prints, and the table of every setting in
docs/settings.md (``ctrlunit config --table``, held to the source by a test).
"""

from __future__ import annotations

from dataclasses import MISSING, Field, dataclass, field, fields
from typing import Any

KINDS = ("value", "flag", "switch", "many", "duration", "period", "priority", "file", "dir",
         "placement", "late")
"""How a flag reads its value: as the field's type (``value``), present or not (``flag``),
``--x/--no-x`` (``switch``), repeatable (``many``), a duration such as ``500us``
(``duration``), a period or ``auto`` (``period``), ``auto`` or a priority (``priority``),
a path (``file``, ``dir``), ``auto``, ``axes`` or a file (``placement``), repeatable
``BLOCK=POLICY`` (``late``)."""


@dataclass(frozen=True)
class Flag:
    """How the command line gives a setting.

    Attributes
    ----------
    name : the flag without ``--``; default: the setting's flat name with ``-`` for ``_``.
    kind : one of :data:`KINDS`.
    default : what the flag shows as its default when it is not the field's (``auto``
        for a period the admission chooses, ``2s`` for a duration); None: the field's.
    metavar : what the help shows for the value.
    everyday : shown by ``--help`` (the others: ``--help-all``).
    hidden : never shown (an option the launcher passes to the roles it starts).
    bare : the value of the flag given without one (``--ros2``: the domain of
        ``ROS_DOMAIN_ID``, or 0); a callable is called when the options are built; None:
        the flag needs its value.
    """

    name: str | None = None
    kind: str = "value"
    default: Any = None
    metavar: str | None = None
    everyday: bool = False
    hidden: bool = False
    bare: Any = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Flag.kind = {self.kind!r}: allowed {', '.join(KINDS)}")


@dataclass(frozen=True)
class About:
    """What a setting's field holds beyond its type and default (its ``metadata``)."""

    help: str
    """What the setting does, for a person choosing it."""
    flag: Flag | None
    """How the command line gives it; None: only the run file and ``--set``."""
    choices: tuple[str, ...] | None
    """The values allowed, if a closed set."""
    bounds: tuple[float, float] | None
    """The closed range allowed of a number (None itself, where the type allows it, is
    not checked)."""
    allowed: str | None
    """How an error states what is allowed, where the choices or bounds do not say it."""
    internal: bool = False
    """The run's own state, not a setting: the launcher, the admission or the warm-up sets
    it (``period_auto`` from ``period = "auto"``, ``central_blocks`` at warm-up), and it
    travels in the run's spec, the configuration handed to a role and a recording. No run
    file, ``--set`` or table offers it (runtime/config/spellings.py)."""
    duration: bool = False
    """A duration without a flag of its own, given as one (``30s``, ``500ms`` or seconds)
    as a flag's ``duration`` is."""

    @property
    def kind(self) -> str:
        """How a user's value of the setting is read (:data:`KINDS`): its flag's kind,
        else ``duration`` or ``value``."""
        if self.flag is not None:
            return self.flag.kind
        return "duration" if self.duration else "value"


def setting(default: Any = MISSING, *, help: str, flag: Flag | None = None,
            choices: tuple[str, ...] | None = None, bounds: tuple[float, float] | None = None,
            allowed: str | None = None, factory: Any = MISSING, internal: bool = False,
            duration: bool = False) -> Any:
    """A field of a section with its :class:`About` (``default`` or ``factory`` as
    :func:`dataclasses.field`'s; ``internal``: the run's state, not a setting)."""
    about = About(help=" ".join(help.split()), flag=flag, choices=choices, bounds=bounds,
                  allowed=allowed, internal=internal, duration=duration)
    if factory is not MISSING:
        return field(default_factory=factory, metadata={"about": about})
    return field(default=default, metadata={"about": about})


def about(f: Field) -> About:
    """The :class:`About` of a section's field.

    Raises
    ------
    TypeError
        If the field was not declared with :func:`setting`."""
    try:
        return f.metadata["about"]
    except KeyError:
        raise TypeError(f"{f.name} is not declared with setting()") from None


def abouts(section: type) -> list[tuple[Field, About]]:
    """Each field of a section with its :class:`About`, in declaration order."""
    return [(f, about(f)) for f in fields(section)]


def allowed_text(a: About) -> str:
    """What an error says is allowed."""
    if a.allowed:
        return a.allowed
    if a.choices:
        return ", ".join(a.choices)
    if a.bounds:
        return f"{a.bounds[0]:g} to {a.bounds[1]:g}"
    return "any"


def user_allowed(a: About) -> str:
    """What a user may give, in any of the setting's spellings: :func:`allowed_text`, with
    ``auto`` for a period and the units of a duration."""
    text = allowed_text(a)
    if a.kind == "period":
        return f"auto, or {text} ({_spellings(a)})"
    if a.kind == "duration":
        return f"{text} ({_spellings(a)})"
    return text


def integers(allowed: str) -> str:
    """What an integer setting allows, said as integers where it is a range (1e3 lies
    between 1 and 1e9, and is refused as no integer)."""
    return f"an integer from {allowed}" if " to " in allowed else allowed


def _spellings(a: About) -> str:
    """A duration's spellings, each example within the setting's bounds."""
    examples = [t for t, s in (("500us", 5e-4), ("2ms", 2e-3), ("30s", 30.0))
                if a.bounds is None or a.bounds[0] <= s <= a.bounds[1]]
    return ", ".join(examples) + (" or seconds" if examples else "seconds")


def out_of_range(a: About, value: Any) -> bool:
    """Whether a value of the setting's type is outside its declared choices or bounds
    (None, where the type allows it, is not checked)."""
    if value is None:
        return False
    if a.choices is not None and value not in a.choices:
        return True
    return a.bounds is not None and not a.bounds[0] <= value <= a.bounds[1]


__all__ = ["KINDS", "About", "Flag", "about", "abouts", "allowed_text", "integers",
           "out_of_range", "setting", "user_allowed"]
