/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Keyboard-wedge gauges: key codes to readings, and the evdev grab. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/input.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include "keyboard.h"

/* HID usage page 7 (keyboard/keypad), the keys a reading uses. */
enum {
	USAGE_ERR_ROLLOVER = 0x01,
	USAGE_1 = 0x1e, USAGE_0 = 0x27, USAGE_ENTER = 0x28, USAGE_MINUS = 0x2d, USAGE_EQUAL = 0x2e,
	USAGE_COMMA = 0x36, USAGE_DOT = 0x37,
	USAGE_KP_MINUS = 0x56, USAGE_KP_PLUS = 0x57, USAGE_KP_ENTER = 0x58, USAGE_KP_1 = 0x59, USAGE_KP_0 = 0x62, USAGE_KP_DOT = 0x63,
	USAGE_KP_COMMA = 0x85,
};

#define MOD_SHIFT 0x22          /* left and right shift */

void hid_kbd_reset(struct hid_kbd *k)
{
	memset(k, 0, sizeof(*k));
}

/* The character a key types in a reading, 0 for none. The top row's
 * digits count shifted or not (layouts such as AZERTY need shift for
 * them); shift and '=' is a plus. */
static char key_char(uint8_t code, bool shift)
{
	if (code >= USAGE_1 && code < USAGE_0)
		return (char)('1' + code - USAGE_1);
	if (code == USAGE_0 || code == USAGE_KP_0)
		return '0';
	if (code >= USAGE_KP_1 && code < USAGE_KP_0)
		return (char)('1' + code - USAGE_KP_1);
	switch (code) {
	case USAGE_MINUS: case USAGE_KP_MINUS: return '-';
	case USAGE_KP_PLUS: return '+';
	case USAGE_EQUAL: return shift ? '+' : 0;
	case USAGE_DOT: case USAGE_KP_DOT: return '.';
	case USAGE_COMMA: case USAGE_KP_COMMA: return ',';
	case USAGE_ENTER: case USAGE_KP_ENTER: return '\n';
	}
	return 0;
}

static bool was_held(const struct hid_kbd *k, uint8_t code)
{
	for (int i = 0; i < 6; i++)
		if (k->held[i] == code)
			return true;
	return false;
}

/* Starts afresh after a reading that went wrong. */
/* Ends the reading being typed with the reason; what was typed is
 * formatted before it is forgotten. */
__attribute__((format(printf, 3, 4)))
static int fail(struct hid_kbd *k, struct asph_error *err, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	asph_error_vset_at(err, -EPROTO, NULL, 0, 0, NULL, fmt, ap);
	va_end(ap);
	hid_kbd_reset(k);
	return -EPROTO;
}

/* The text typed as a number: an optional sign, digits with one point
 * (a comma is a decimal point too). */
static int finish(struct hid_kbd *k, double *value, struct asph_error *err)
{
	char buf[HID_KBD_TEXT_MAX + 1], *end;
	size_t points = 0, digits = 0;

	for (size_t i = 0; i < k->len; i++) {
		char c = k->text[i] == ',' ? '.' : k->text[i];
		buf[i] = c;
		if ((c == '-' || c == '+') && i != 0) {
			buf[k->len] = '\0';
			return fail(k, err, "the gauge typed a sign inside its reading");
		}
		points += c == '.';
		digits += c >= '0' && c <= '9';
	}
	buf[k->len] = '\0';
	if (!digits || points > 1)
		return fail(k, err, "the gauge typed '%s', which is not a number", buf);
	*value = strtod(buf, &end);
	hid_kbd_reset(k);
	return isfinite(*value) && !*end ? 1 : asph_error_set(err, -EPROTO, "not a number");
}

int hid_kbd_feed(struct hid_kbd *k, uint8_t report_id, const uint8_t *rep, size_t n,
		 double *value, struct asph_error *err)
{
	if (report_id) {
		if (n == 0 || rep[0] != report_id)
			return fail(k, err, "keyboard report id %u is not the gauge's (%u)",
				    n ? rep[0] : 0u, report_id);
		rep++;
		n--;
	}
	if (n != 8)
		return fail(k, err, "a keyboard report of %zu bytes (boot protocol: 8)", n);
	bool shift = rep[0] & MOD_SHIFT;
	const uint8_t *keys = rep + 2;
	if (keys[0] == USAGE_ERR_ROLLOVER)
		return fail(k, err, "the keyboard reports an error (roll-over)");
	int r = 0;
	for (int i = 0; i < 6 && r == 0; i++) {
		uint8_t code = keys[i];
		if (!code || was_held(k, code))
			continue;
		char c = key_char(code, shift);
		if (!c) {
			r = fail(k, err, "the gauge typed key 0x%02x, which has no place in a reading",
				 code);
			break;
		}
		if (c == '\n') {
			r = finish(k, value, err);
			break;
		}
		if (k->len == HID_KBD_TEXT_MAX) {
			r = fail(k, err, "the gauge typed more than 24 characters without Enter");
			break;
		}
		k->text[k->len++] = c;
	}
	if (r >= 0)
		memcpy(k->held, keys, 6);
	return r;
}

int hid_kbd_grab(const char *hidraw, int *fd, char *node, size_t size, struct asph_error *err)
{
	const char *name = strrchr(hidraw, '/');
	char dir[256];

	*fd = -1;
	node[0] = '\0';
	snprintf(dir, sizeof(dir), "/sys/class/hidraw/%s/device/input", name ? name + 1 : hidraw);
	DIR *inputs = opendir(dir);
	if (!inputs)
		return 0;               /* no input device: nothing types anywhere */
	struct dirent *in;
	while (*fd < 0 && (in = readdir(inputs))) {
		char sub[512];
		if (strncmp(in->d_name, "input", 5))
			continue;
		snprintf(sub, sizeof(sub), "%s/%s", dir, in->d_name);
		DIR *events = opendir(sub);
		struct dirent *ev;
		while (events && (ev = readdir(events))) {
			if (strncmp(ev->d_name, "event", 5))
				continue;
			snprintf(node, size, "/dev/input/%s", ev->d_name);
			*fd = open(node, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
			if (*fd < 0) {
				int e = errno;
				closedir(events);
				closedir(inputs);
				return asph_error_set(err, e == EACCES ? -EACCES : -ENODEV,
						      "cannot open the gauge's keyboard node %s to grab it: %s",
						      node, strerror(e));
			}
			break;
		}
		if (events)
			closedir(events);
	}
	closedir(inputs);
	if (*fd >= 0 && ioctl(*fd, EVIOCGRAB, (void *)1) < 0) {
		int e = errno;
		close(*fd);
		*fd = -1;
		return asph_error_set(err, e == EBUSY ? -EBUSY : -EIO,
				      "cannot grab the gauge's keyboard node %s: %s%s", node, strerror(e),
				      e == EBUSY ? " (another program holds it)" : "");
	}
	return 0;
}
