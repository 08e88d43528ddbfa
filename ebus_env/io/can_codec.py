"""Pack and unpack DBC signals for many CAN frames at once.

cantools reads the DBC and holds each signal's layout (start bit, length, byte order, sign,
scale, offset); it decodes one frame per call, about 10 us each, which is 10 s for a bus's day
of some 900,000 frames. This module applies the same layouts to arrays of frames with numpy
bit operations (the tests check it against cantools frame by frame, both ways). Classic CAN
frames (up to 8 data bytes) and signals up to 64 bits; other messages (CAN FD payloads,
multiplexed messages) go through cantools frame by frame (:func:`decode_slow`).

Bit numbering (Vector's DBC convention, as cantools reads it): a little-endian (Intel)
signal starts at its least significant bit, counted from bit 0 of byte 0 upwards; a
big-endian (Motorola) signal's start is its most significant bit in the "sawtooth" numbering
(byte 0 holds bits 7..0, byte 1 bits 15..8, ...). With the 8 data bytes read as one
little-endian 64-bit word ``w_le`` and as one big-endian word ``w_be``:

    raw = (w_le >> start) & (2^n - 1)                       (little-endian)
    raw = (w_be >> (64 - (m + n))) & (2^n - 1),  m = 8 (start // 8) + 7 - start % 8
                                                            (big-endian; m: the MSB's index
                                                             counted from byte 0's top bit)
    physical = offset + scale * raw   (raw as two's complement for a signed signal)
"""

from __future__ import annotations

import numpy as np

WIDTH = 8
"""Data bytes of a classic CAN frame: the fast path's word."""


def fast(message) -> bool:
    """Whether a cantools message can go through the vectorized path."""
    return (message.length <= WIDTH and not message.is_multiplexed()
            and all(s.length <= 64 for s in message.signals))


def _words(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The frames' first 8 data bytes (rows of ``data``, uint8) as little- and big-endian
    64-bit words."""
    padded = np.zeros((len(data), WIDTH), dtype=np.uint8)
    padded[:, :min(WIDTH, data.shape[1])] = data[:, :WIDTH]
    return padded.view("<u8").ravel(), padded.view(">u8").ravel().astype(np.uint64)


def _shift(signal) -> int:
    """Right shift that brings the signal's least significant bit to bit 0 of its word."""
    if signal.byte_order == "little_endian":
        return signal.start
    msb = 8 * (signal.start // 8) + 7 - signal.start % 8
    return 64 - (msb + signal.length)


def raw_values(data: np.ndarray, signal) -> np.ndarray:
    """The signal's raw integer values (int64; uint64 for an unsigned 64-bit signal) in the
    frames ``data`` (n x bytes, uint8)."""
    le, be = _words(data)
    word = le if signal.byte_order == "little_endian" else be
    mask = np.uint64((1 << signal.length) - 1)
    raw = (word >> np.uint64(_shift(signal))) & mask
    if signal.is_float:
        kind = {32: "<u4", 64: "<u8"}[signal.length]
        floats = {32: np.float32, 64: np.float64}[signal.length]
        return raw.astype(kind).view(floats).astype(float)
    if signal.is_signed:
        out = raw.astype(np.int64)
        if signal.length < 64:  # sign extension, (x ^ s) - s, without leaving int64
            sign = np.int64(1 << (signal.length - 1))
            out = (out ^ sign) - sign
        return out
    return raw if signal.length == 64 else raw.astype(np.int64)


def physical(raw: np.ndarray, signal) -> np.ndarray:
    """Raw values scaled to the signal's unit: ``offset + scale * raw`` (floats)."""
    return signal.offset + signal.scale * raw.astype(float)


def decode_slow(data: np.ndarray, lengths: np.ndarray, message) -> dict[str, np.ndarray]:
    """Physical values of every signal of ``message``, frame by frame through cantools (CAN FD
    and multiplexed messages); NaN where a frame does not carry the signal."""
    out = {s.name: np.full(len(data), np.nan) for s in message.signals}
    for i, (row, n) in enumerate(zip(data, lengths, strict=True)):
        values = message.decode(bytes(row[:n]), decode_choices=False, scaling=True,
                                allow_truncated=False)
        for name, value in values.items():
            out[name][i] = float(value)
    return out


def encode(message, raw: dict[str, np.ndarray], n: int) -> np.ndarray:
    """Frames (n x message.length, uint8) of ``message`` holding the raw integer values
    ``raw`` (by signal name); signals not given are all ones (J1939's "not available")."""
    if not fast(message):
        raise ValueError(f"encode: message {message.name} is not a classic CAN frame without "
                         "multiplexing")
    le = np.zeros(n, dtype=np.uint64)
    be = np.zeros(n, dtype=np.uint64)
    for s in message.signals:
        mask = (1 << s.length) - 1
        value = raw.get(s.name)
        bits = np.full(n, mask, dtype=np.uint64) if value is None else \
            (np.asarray(value).astype(np.int64).astype(np.uint64) & np.uint64(mask))
        shifted = bits << np.uint64(_shift(s))
        if s.byte_order == "little_endian":
            le |= shifted
        else:
            be |= shifted
    data = le.astype("<u8").view(np.uint8).reshape(n, WIDTH) | \
        be.astype(">u8").view(np.uint8).reshape(n, WIDTH)
    return np.ascontiguousarray(data[:, :message.length])


def to_raw(values: np.ndarray, signal) -> np.ndarray:
    """Physical values as the signal's raw integers (rounded to its resolution, as cantools
    encodes them); a value the raw range cannot hold raises ValueError."""
    raw = np.rint((np.asarray(values, dtype=float) - signal.offset) / signal.scale)
    low, high = (-(1 << (signal.length - 1)), (1 << (signal.length - 1)) - 1) \
        if signal.is_signed else (0, (1 << signal.length) - 1)
    bad = np.flatnonzero(~np.isfinite(raw) | (raw < low) | (raw > high))
    if bad.size:
        raise ValueError(f"signal {signal.name}: value {values[bad[0]]!r} does not fit its "
                         f"{signal.length} bits (scale {signal.scale:g}, offset {signal.offset:g})")
    return raw.astype(np.int64)
