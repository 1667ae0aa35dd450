"""The user-data types of a swarm, as IDL structs, and their CDR payload encoding.

IDL equivalent (module ``swarmd``, every struct ``@final``, XCDR1 encoding)::

    enum CommandKind { TAKEOFF, LAND, HOLD, ABORT };
    enum CommandResult { ACCEPTED, COMPLETED, REJECTED, FAILED };
    struct Readiness {                 // swarm/ready, member -> commander
      string<64> node; uint32 seq; boolean ready; string<128> reason; boolean armed;
      uint8 landed_state; uint8 gps_fix; uint8 satellites; int8 battery_pct;
      uint16 link_q_permille;
      uint32 stamp_ms;                 // the member's clock when sent, ms mod 2^32
    };
    struct TimeEcho {                  // one member's last report, as the commander saw it
      string<64> node; uint32 stamp_ms; uint32 age_ms;
      uint32 epoch;                    // the member's boot epoch that report was sealed in
    };
    struct Command {                   // swarm/command, commander -> members
      uint64 command_id; CommandKind kind; float altitude_m;
      sequence<string<64>, 255> targets;   // on the wire: the receiving member only
      uint32 valid_ms;                     // validity from issue, commander's ms; 0 = none
      sequence<TimeEcho, 255> echoes;      // on the wire: the receiving member's echo only
    };
    struct CommandOutcome {            // swarm/outcome, member -> commander
      uint64 command_id; string<64> node; CommandResult result; string<128> reason;
      uint8 flags;                     // OUTCOME_NOT_SAVED, _NOW_SAVED, _DISARM_UNCONFIRMED
      uint32 save_gen;                 // the member's state-file writes answered in its life
    };                                 // flags and save_gen: on the wire only when not 0

The payload is a SerializedPayload (DDSI-RTPS 2.5 section 10.2): a 4-byte encapsulation
header (CDR_LE ``00 01``, options) followed by the XCDR1 body; the body is padded to a
multiple of 4 and the two low bits of the options' second byte say how many padding octets
were added (section 10.2, "representation options", RTPS 2.3 and later).

``CommandOutcome.flags`` is appended to a ``@final`` struct, and written only when it is
not 0: an outcome without a flag has the layout of earlier builds, byte for byte, and a
receiver reads a body that ends before ``flags`` as flags 0 (``_OutcomeWithoutFlags``). So a
commander of an earlier build reads a flagged outcome (the IDL layer ignores the unread
tail) and this build reads an earlier member's (docs/wire.md, "The outcome's flags").
``save_gen`` (session 15) follows ``flags`` the same way: both are written only when one of
them is not 0, a session-14 receiver leaves it unread, and this build reads a body that ends
after ``flags`` as ``save_gen`` 0 (``_OutcomeFlagsOnly``). It orders a member's word on its
record: the commander applies a mark (``OUTCOME_NOT_SAVED``) or its clear
(``OUTCOME_NOW_SAVED``) only if it is newer than the last one it applied
(docs/dataplane.md, "A failed save").

Invariant: ``decode_sample`` raises ``PayloadError`` and nothing else for any input, and
every value it returns has passed ``validate``.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Annotated, Final, TypeVar

from cyclonedds_idl import IdlEnum, IdlStruct
from cyclonedds_idl._support import Endianness  # not re-exported by the package
from cyclonedds_idl.types import bounded_str, float32, int8, sequence, uint8, uint16, uint32, uint64

MAX_NAME_CHARS: Final = 64  # a participant name in the bundle; also bounds the wire string
MAX_REASON_CHARS: Final = 128
# Targets (and echoes) of one received command sample. Each member receives its own copy,
# naming itself and carrying its echo (docs/dataplane.md, "One copy per member"), so a
# sample from a swarmd commander holds one; the bound only refuses garbage. The commander's
# own ``Command`` (before it is split into copies) is bounded by the bundle instead.
MAX_TARGETS: Final = 255
MAX_ALTITUDE_M: Final = 500.0  # above any legal small-UAS ceiling; rejects garbage altitudes
MAX_LINK_Q_PERMILLE: Final = 1000
# ``CommandOutcome.flags``: the member's record of this decision could not be written to its
# state file (docs/dataplane.md, "A failed save"). The other bits are reserved: sent 0,
# ignored on receipt, so a later build's flag does not make this one drop the outcome.
OUTCOME_NOT_SAVED: Final = 0x01
# ``CommandOutcome.flags`` (session 15): a decision its member told unsaved is on disk after
# all (a later write held it), so the commander clears the row's mark; ``save_gen`` orders
# the two (a replayed or reordered older mark cannot set it again).
OUTCOME_NOW_SAVED: Final = 0x02
# ``CommandOutcome.flags`` (session 18): the FAILED take-off this answers left its DISARM
# unconfirmed, so the vehicle may still be armed; sent again with the failure's result and
# reason up to 2 s after it (docs/px4.md, "A failed take-off's DISARM"). An amendment the
# commander marks on the row (``disarm_unconfirmed``), never a second execution.
OUTCOME_DISARM_UNCONFIRMED: Final = 0x04
# The flags this build reads; what an outcome's dedup keys (``received.py``): a reserved bit
# set on an answer already taken must not make it new (docs/wire.md, "The outcome's flags").
OUTCOME_KNOWN_FLAGS: Final = OUTCOME_NOT_SAVED | OUTCOME_NOW_SAVED | OUTCOME_DISARM_UNCONFIRMED
# A command's validity (docs/dataplane.md, "Validity"): longer than any operator means, short
# of the wrap of the u32 millisecond stamps; a value above is garbage, not a long validity.
MAX_VALID_MS: Final = 600_000

NodeName = Annotated[str, bounded_str(MAX_NAME_CHARS)]
Reason = Annotated[str, bounded_str(MAX_REASON_CHARS)]

# Encapsulation identifiers (DDSI-RTPS 2.5 section 10.5, table 10.3); always big-endian octets.
ENCAPSULATION_CDR_BE: Final = b"\x00\x00"
ENCAPSULATION_CDR_LE: Final = b"\x00\x01"
ENCAPSULATION_HEADER_SIZE: Final = 4
PADDING_MASK: Final = 0x03  # low bits of options[1]: number of padding octets at the end


class PayloadError(ValueError):
    """A serialized payload that is not a valid sample of the expected type."""


class CommandKind(IdlEnum, typename="swarmd::CommandKind"):
    TAKEOFF = 0
    LAND = 1
    HOLD = 2
    ABORT = 3


class CommandResult(IdlEnum, typename="swarmd::CommandResult"):
    ACCEPTED = 0  # received and handed to the autopilot (PX4 COMMAND_ACK accepted)
    COMPLETED = 1  # the vehicle reached the commanded state
    REJECTED = 2  # refused before execution (not ready, not a target of this command...)
    FAILED = 3  # tried and failed (autopilot denied, timed out)


@dataclass
class Readiness(IdlStruct, typename="swarmd::Readiness"):
    """One member's pre-flight verdict, published at 1 Hz on ``swarm/ready``."""

    node: NodeName
    seq: uint32  # publisher's sample counter from 1: "the 20th message" of the paper's benchmark
    ready: bool
    reason: Reason  # the first failing check, "" when ready
    armed: bool
    landed_state: uint8  # MAV_LANDED_STATE (0 undefined, 1 on ground, 2 in air, 3/4 take-off/land)
    gps_fix: uint8  # GPS_FIX_TYPE (0 no GPS .. 3 3D fix .. 6 RTK fixed)
    satellites: uint8  # 255 = unknown, as MAVLink GPS_RAW_INT
    battery_pct: int8  # -1 = unknown, as MAVLink SYS_STATUS.battery_remaining
    link_q_permille: uint16  # the link quality Q of paper eq. 2, in thousandths
    # The member's monotonic clock when it sent this, in ms mod 2^32: the commander echoes
    # it in commands, so the member can date a command on its own clock (validity).
    stamp_ms: uint32 = 0


@dataclass
class TimeEcho(IdlStruct, typename="swarmd::TimeEcho"):
    """The last readiness report of ``node`` the commander holds when it issues a command:
    the member's own ``stamp_ms`` from it, and ``age_ms``, how long before the command was
    issued the commander received it (commander's clock), and ``epoch``, the member's boot
    epoch the commander's plane authenticated that report under: the life whose clock the
    stamp is on. See docs/dataplane.md, "Validity" and "A life runs only its own commands"."""

    node: NodeName
    stamp_ms: uint32
    age_ms: uint32
    # the member refuses an echo of another life (its clock may have started again)
    epoch: uint32


@dataclass
class Command(IdlStruct, typename="swarmd::Command"):
    """A swarm command. ``command_id`` is unique per commander across restarts, see
    ``docs/dataplane.md`` (exactly-once)."""

    command_id: uint64
    kind: CommandKind
    altitude_m: float32  # TAKEOFF only; 0 otherwise
    # empty = every member; a member's copy names that member only (DataPlane.send_command)
    targets: Annotated[Sequence[NodeName], sequence(NodeName, MAX_TARGETS)]
    # How long after issue the command stays right to run, commander's ms; 0: no validity
    # (a member refuses it as ``expired``: it cannot show the command is still right).
    valid_ms: uint32 = 0
    echoes: Annotated[Sequence[TimeEcho], sequence(TimeEcho, MAX_TARGETS)] = field(
        default_factory=list
    )


@dataclass
class CommandOutcome(IdlStruct, typename="swarmd::CommandOutcome"):
    """What a member did with one command, sent back on ``swarm/outcome``. ``flags``:
    ``OUTCOME_NOT_SAVED`` (its record could not be written), else 0 (see the module
    docstring for the layout)."""

    command_id: uint64
    node: NodeName
    result: CommandResult
    reason: Reason
    flags: uint8 = 0
    # The member's count of state-file writes answered in its life when it sent this: orders
    # its marks and clears (``OUTCOME_NOT_SAVED``/``OUTCOME_NOW_SAVED``); 0 with no flag
    save_gen: uint32 = 0


@dataclass
class _OutcomeFlagsOnly(IdlStruct, typename="swarmd::_OutcomeFlagsOnly"):
    """``CommandOutcome`` as session 14 writes a flagged one: no ``save_gen``. Never a
    bundle type."""

    command_id: uint64
    node: NodeName
    result: CommandResult
    reason: Reason
    flags: uint8


@dataclass
class _OutcomeWithoutFlags(IdlStruct, typename="swarmd::_OutcomeWithoutFlags"):
    """``CommandOutcome`` as earlier builds write it, and as this one writes it when
    ``flags`` is 0: the same fields without the last. Never a bundle type."""

    command_id: uint64
    node: NodeName
    result: CommandResult
    reason: Reason


Sample = Readiness | Command | CommandOutcome
SampleT = TypeVar("SampleT", bound=Readiness | Command | CommandOutcome)

# The type names a bundle may declare, and the struct that carries each.
TYPES_BY_NAME: Final[dict[str, type[Readiness] | type[Command] | type[CommandOutcome]]] = {
    "swarmd::Readiness": Readiness,
    "swarmd::Command": Command,
    "swarmd::CommandOutcome": CommandOutcome,
}

_U8: Final = range(0, 1 << 8)
_I8: Final = range(-(1 << 7), 1 << 7)
_U32: Final = range(0, 1 << 32)
_U64: Final = range(0, 1 << 64)


def _check_str(value: object, field: str, limit: int) -> None:
    if not isinstance(value, str):
        raise PayloadError(f"{field} must be a string")
    if len(value.encode("utf-8")) > limit or "\x00" in value:
        raise PayloadError(f"{field} longer than {limit} octets or holding NUL")


def _check_int(value: object, field: str, allowed: range) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value not in allowed:
        raise PayloadError(f"{field}={value!r} outside {allowed.start}..{allowed.stop - 1}")


def validate(sample: Sample) -> None:
    """Check every field against the IDL bounds and swarmd's value ranges.

    The Cyclone IDL layer does not enforce string bounds or value ranges on decode, so a
    peer's sample passes here before the application sees it. Raises ``PayloadError``.
    """
    if isinstance(sample, Readiness):
        _check_str(sample.node, "node", MAX_NAME_CHARS)
        _check_int(sample.seq, "seq", _U32)
        _check_str(sample.reason, "reason", MAX_REASON_CHARS)
        for name in ("landed_state", "gps_fix", "satellites"):
            _check_int(getattr(sample, name), name, _U8)
        _check_int(sample.battery_pct, "battery_pct", range(-1, 101))
        _check_int(sample.link_q_permille, "link_q_permille", range(MAX_LINK_Q_PERMILLE + 1))
        _check_int(sample.stamp_ms, "stamp_ms", _U32)
        flags: tuple[object, object] = (sample.ready, sample.armed)
        if not all(isinstance(flag, bool) for flag in flags):
            raise PayloadError("ready and armed must be booleans")
    elif isinstance(sample, Command):
        _check_int(sample.command_id, "command_id", _U64)
        kind: object = sample.kind
        if not isinstance(kind, CommandKind):
            raise PayloadError(f"kind={kind!r} is not a CommandKind")
        alt: object = sample.altitude_m
        if not isinstance(alt, float | int) or not math.isfinite(alt):
            raise PayloadError(f"altitude_m={alt!r} is not a finite number")
        if sample.kind == CommandKind.TAKEOFF and not 0.0 < alt <= MAX_ALTITUDE_M:
            raise PayloadError(f"TAKEOFF altitude_m={alt} outside (0, {MAX_ALTITUDE_M}]")
        if len(sample.targets) > MAX_TARGETS:
            raise PayloadError(f"{len(sample.targets)} targets exceed {MAX_TARGETS}")
        for target in sample.targets:
            _check_str(target, "targets[]", MAX_NAME_CHARS)
        _check_int(sample.valid_ms, "valid_ms", range(MAX_VALID_MS + 1))
        if len(sample.echoes) > MAX_TARGETS:
            raise PayloadError(f"{len(sample.echoes)} echoes exceed {MAX_TARGETS}")
        for echo in sample.echoes:
            if not isinstance(echo, TimeEcho):
                raise PayloadError("echoes[] must be TimeEcho")
            _check_str(echo.node, "echoes[].node", MAX_NAME_CHARS)
            _check_int(echo.stamp_ms, "echoes[].stamp_ms", _U32)
            _check_int(echo.age_ms, "echoes[].age_ms", _U32)
            _check_int(echo.epoch, "echoes[].epoch", _U32)
    else:
        _check_int(sample.command_id, "command_id", _U64)
        _check_str(sample.node, "node", MAX_NAME_CHARS)
        result: object = sample.result
        if not isinstance(result, CommandResult):
            raise PayloadError(f"result={result!r} is not a CommandResult")
        _check_str(sample.reason, "reason", MAX_REASON_CHARS)
        _check_int(sample.flags, "flags", _U8)
        _check_int(sample.save_gen, "save_gen", _U32)


def encode_sample(sample: Sample) -> bytes:
    """The SerializedPayload of ``sample``: CDR_LE header, XCDR1 body, padded to 4 octets.

    Raises ``PayloadError`` if the sample breaks a bound (a caller's bug, never network input).
    """
    validate(sample)
    written: IdlStruct = sample
    if isinstance(sample, CommandOutcome) and not (sample.flags or sample.save_gen):
        # the earlier builds' layout, byte for byte: no flag, no new octet
        written = _OutcomeWithoutFlags(sample.command_id, sample.node, sample.result, sample.reason)
    try:
        raw = written.serialize(endianness=Endianness.Little, use_version_2=False)
    except Exception as exc:  # the IDL layer raises bare Exception for out-of-range values
        raise PayloadError(f"cannot serialize {type(sample).__name__}: {exc}") from None
    if raw[:2] != ENCAPSULATION_CDR_LE:
        raise PayloadError(f"IDL layer wrote encapsulation {raw[:2].hex()}, expected 0001")
    padding = -len(raw) % 4
    options = bytes((0, padding))
    return ENCAPSULATION_CDR_LE + options + raw[ENCAPSULATION_HEADER_SIZE:] + bytes(padding)


def _outcome_without_flags(body: bytes) -> CommandOutcome:
    """An outcome whose body ends before ``save_gen`` (session 14's flagged layout: gen 0)
    or before ``flags`` (an earlier build's, or this build's without a flag: flags 0).
    Raises ``PayloadError`` when it is neither."""
    try:
        flagged = _OutcomeFlagsOnly.deserialize(body, has_header=True)
    except Exception:  # noqa: S110 - not that layout: try the earliest one
        pass
    else:
        return CommandOutcome(
            flagged.command_id, flagged.node, flagged.result, flagged.reason, flagged.flags
        )
    try:
        old = _OutcomeWithoutFlags.deserialize(body, has_header=True)
    except Exception as exc:  # as in decode_sample
        raise PayloadError(f"malformed CommandOutcome payload: {exc}") from None
    return CommandOutcome(old.command_id, old.node, old.result, old.reason)


def decode_sample(payload: bytes, cls: type[SampleT]) -> SampleT:
    """Parse a SerializedPayload as ``cls``. Raises ``PayloadError`` and nothing else."""
    if len(payload) < ENCAPSULATION_HEADER_SIZE:
        raise PayloadError(f"payload of {len(payload)} octets has no encapsulation header")
    kind = payload[:2]
    if kind not in (ENCAPSULATION_CDR_LE, ENCAPSULATION_CDR_BE):
        raise PayloadError(f"encapsulation {kind.hex()} is not CDR_LE/CDR_BE (XCDR1)")
    padding = payload[3] & PADDING_MASK
    body_end = len(payload) - padding
    if body_end < ENCAPSULATION_HEADER_SIZE:
        raise PayloadError(f"{padding} padding octets exceed the payload")
    try:
        sample = cls.deserialize(payload[:body_end], has_header=True)
    except Exception as exc:  # struct.error, UnicodeDecodeError, enum ValueError, bare Exception
        if cls is not CommandOutcome:
            raise PayloadError(f"malformed {cls.__name__} payload: {exc}") from None
        sample = _outcome_without_flags(payload[:body_end])
    if not isinstance(sample, cls):  # pragma: no cover - the IDL layer builds cls or raises
        raise PayloadError(f"IDL layer returned {type(sample).__name__}, not {cls.__name__}")
    validate(sample)
    return sample
