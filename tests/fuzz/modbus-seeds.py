#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Writes the seed corpus of the Modbus fuzz target (fuzz-modbus.c says
the input's format): the answers a sensor of each map and an AZ stage give
the driver's requests, in the order the driver asks, and a few refusals;
over TCP, and some over RTU.

    tests/fuzz/modbus-seeds.py tests/fuzz/corpus/modbus
"""
import os
import struct
import sys

READY, HOME_END, ALM, IN_POS = 1 << 5, 1 << 4, 1 << 7, 1 << 14   # the AZ's status bits
ECHO = bytes([0])                       # a write's answer


def regs(*words):
    """The answer that fits a read: these 16-bit registers."""
    return bytes([0]) + b''.join(struct.pack('>H', w & 0xffff) for w in words)


def exception(code):
    return bytes([1, code])


def raw(data, framed):
    """Unit and PDU as they are, or framed (the CRC, the MBAP header)."""
    return bytes([2 | (4 if framed else 0), len(data)]) + bytes(data)

RTU = 0x80      # byte 1: the line is RTU


def s32(v, low_first=False):
    hi, lo = (v >> 16) & 0xffff, v & 0xffff
    return (lo, hi) if low_first else (hi, lo)


def f32(v, low_first=False):
    hi, lo = struct.unpack('>HH', struct.pack('>f', v))
    return (lo, hi) if low_first else (hi, lo)


def stage(wide=True, low_first=False, start_bit=False):
    """An AZ stage's answers: open, status, homing, position, a move to
    (1, 0.5, -1) at 100 counts a unit."""
    def w(v):
        return s32(v, low_first) if wide else (v & 0xffff,)
    s = (regs(*w(READY | HOME_END)) + ECHO) * 3                  # open
    s += (regs(*w(READY | HOME_END)) + regs(*w(0))) * 3           # status
    s += regs(*w(READY)) * 3                                      # homing: no alarm
    s += ECHO + regs(*w(READY | HOME_END)) + ECHO                 # z home
    s += ECHO * 2 + (regs(*w(READY | HOME_END)) + ECHO) * 2       # x and y
    s += regs(*w(0)) * 3                                          # position
    s += (ECHO * (2 if start_bit else 1)) * 3                     # the data blocks
    for target in (100, 50, -100):                                # in position
        s += regs(*w(READY | IN_POS)) + regs(*w(target)) + (ECHO if start_bit else b'')
    return s


def seeds():
    probe = regs(*s32(12345)) * 3
    yield 'probe-custom-s32', bytes([0x00, 0]) + probe
    yield 'probe-custom-valid', bytes([0x01, 0]) + (regs(*s32(-2000)) + regs(8)) * 2 + \
        regs(*s32(7)) + regs(0)
    yield 'probe-custom-u16-holding', bytes([0x01 | 3 << 2 | 0x40, 0]) + (regs(40000) + regs(8)) * 3
    yield 'probe-custom-f32-low-first', bytes([4 << 2 | 0x20, 0]) + regs(*f32(1.25, True)) * 3
    # Orbit ACS: the float image, then the reading status (19: over range)
    yield 'probe-orbit', bytes([0x02, 0]) + regs(*f32(1.25)) + regs(0) + \
        regs(*f32(1.25)) + regs(19) + regs(*f32(1.25)) + regs(0)
    yield 'probe-orbit-no-probe', bytes([0x02, 0]) + regs(*f32(1.25)) + regs(247)
    # RF60x: serial, base distance 30 mm, range 10 mm; mid-range, saturated
    yield 'probe-rf60x', bytes([0x03, 0]) + regs(4711, 30, 10) + regs(0x2000) * 2 + regs(0x4000)
    yield 'probe-exception', bytes([0x00, 0]) + exception(2)
    # a frame of another unit, a byte count that lies; each retried
    yield 'probe-wrong-unit', bytes([0x00, 0]) + raw([9, 4, 4, 0, 0, 0, 1], True) + probe
    yield 'probe-short-count', bytes([0x00, 0]) + raw([1, 4, 2, 0, 0], True) + probe
    yield 'probe-silence-then-answer', bytes([0x00, 0]) + bytes([3]) + probe
    yield 'stage-az', bytes([0x80, 0]) + probe + stage()
    yield 'stage-16bit-low-first-start', bytes([0x80, 1 | 2 | 4]) + probe + \
        stage(wide=False, low_first=True, start_bit=True)
    yield 'stage-rtz', bytes([0x80, 8]) + probe + stage()
    # over RTU: a sensor, a bad CRC (retried), an exception, the stage
    yield 'rtu-probe-custom-s32', bytes([0x00, RTU]) + probe
    yield 'rtu-probe-bad-crc', bytes([0x00, RTU]) + \
        raw([1, 4, 4, 0, 0, 0x30, 0x39, 0xde, 0xad], False) + probe
    yield 'rtu-probe-exception', bytes([0x00, RTU]) + exception(2)
    yield 'rtu-stage-az', bytes([0x80, RTU]) + probe + stage()
    # an alarm on x: the status says so with its code, homing refuses
    yield 'stage-alarm', bytes([0x80, 0]) + probe + (regs(0, 0x30) + ECHO) * 3 + \
        regs(0, ALM | READY) + regs(0, 0) + regs(0, 0x42) + (regs(0, 0x30) + regs(0, 0)) * 2 + \
        regs(0, ALM) + regs(0, 0x42)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__),
                                                              'corpus', 'modbus')
    for name, data in seeds():
        with open(os.path.join(out, name), 'wb') as f:
            f.write(data)


if __name__ == '__main__':
    main()
