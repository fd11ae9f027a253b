/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Keyboard-wedge gauges: cables (Mitutoyo USB-ITN, many indicator cables)
 * that type a reading as keystrokes ("-12.345" Enter) in boot-protocol
 * keyboard input reports. The decoder is pure (reports in, readings
 * out); the grab of the keyboard's evdev node keeps the keystrokes from
 * the desktop. docs/driver-hid.md. Internal to drivers/hid/.
 */
#ifndef ASPH_HID_KEYBOARD_H
#define ASPH_HID_KEYBOARD_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

#define HID_KBD_TEXT_MAX 24     /* characters of one reading */

struct hid_kbd {
	uint8_t held[6];        /* the keys down in the last report */
	char text[HID_KBD_TEXT_MAX + 1];
	size_t len;
};

void hid_kbd_reset(struct hid_kbd *k);

/*
 * Feeds one boot-protocol keyboard report (modifier byte, reserved
 * byte, six key codes; report_id first when not 0). Keys newly down are
 * typed: digits (top row, shifted or not, and keypad), '-' and '+' signs,
 * '.' and ',' decimal points (keypad too); Enter or keypad Enter ends
 * the reading. 1 with *value when a reading is complete, 0 when more is
 * to come, -EPROTO with a reason for a key a reading has no place for, a
 * report of the wrong size or id, a keyboard error (roll-over) or a text
 * that is not a number; after an error the decoder starts afresh.
 */
int hid_kbd_feed(struct hid_kbd *k, uint8_t report_id, const uint8_t *rep, size_t n,
		 double *value, struct asph_error *err);

/*
 * Grabs the evdev node of the HID device whose hidraw node is hidraw
 * (EVIOCGRAB), so that the keystrokes reach no one else. *fd is the
 * grabbed node (close() releases it), or -1 when the device has none.
 * -EBUSY when another program holds it.
 */
int hid_kbd_grab(const char *hidraw, int *fd, char *node, size_t size,
		 struct asph_error *err);

#endif
