/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The connection of a line device: a TCP client or a serial port set up
 * through termios (baud, data bits, parity, stop bits, RTS/CTS, DTR), as a
 * transport (drivers/transport.h). Internal to drivers/line/.
 */
#ifndef ASPH_LINE_LINK_H
#define ASPH_LINE_LINK_H

#include <stdbool.h>

#include "asph/error.h"
#include "transport.h"

struct line_link_params {
	bool serial;
	const char *host;
	int port;
	const char *device;
	int baud, data_bits, stop_bits;
	char parity;                    /* 'N', 'E', 'O' */
	bool rtscts;
	int dtr;                        /* 1 raise, 0 lower, -1 leave */
};

/* Connects (TCP within timeout_ms) or opens and sets up the port; the
 * transport owns the descriptor. -ENODEV nobody there, -EACCES not
 * allowed, -EINVAL a setting the port refuses, each with the reason. */
int line_link_open(const struct line_link_params *p, unsigned timeout_ms,
		   struct transport **out, struct asph_error *err);

/*
 * Pulses DTR (up, ms, down) on a serial port: the data request of
 * gauges whose cable has one. -ENOTSUP with the reason on a line without
 * modem control (a TCP connection, a pseudo-terminal).
 */
int line_link_dtr_pulse(struct transport *t, unsigned ms, struct asph_error *err);

/* Writes bytes straight to the descriptor within ms, bypassing a
 * cancelled transport: the stop command after stop(). Best effort. */
void line_link_send_raw(struct transport *t, const char *buf, size_t len, unsigned ms);

#endif
