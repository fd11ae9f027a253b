/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The byte transport under a driver's protocol: one file descriptor (a
 * SocketCAN socket, a serial port, a TCP connection, or in tests one end of
 * a socketpair with a simulator on the other), with the driver ABI's rules
 * built in: every call has a timeout, stop() from another thread interrupts
 * a call that waits, and failures come back as the ABI's codes with a
 * reason (-ETIMEDOUT, -ECANCELED, -ENODEV when the peer went away, -EIO).
 * Internal to drivers/.
 */
#ifndef ASPH_TRANSPORT_H
#define ASPH_TRANSPORT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

struct transport;

/* Wraps fd (made non-blocking; closed by transport_free when own). name
 * prefixes every reason, e.g. "can0". */
int transport_new(int fd, bool own, const char *name, struct transport **out,
		  struct asph_error *err);
void transport_free(struct transport *t);
int transport_fd(const struct transport *t);

/* Writes all len bytes (a stream) or one message (a datagram or seqpacket
 * socket) within timeout_ms. */
int transport_send(struct transport *t, const void *buf, size_t len,
		   unsigned timeout_ms, struct asph_error *err);

/* Reads what is there, at most size bytes (one message on a message
 * socket), waiting at most timeout_ms for the first byte. *got > 0 on
 * success. */
int transport_recv(struct transport *t, void *buf, size_t size, size_t *got,
		   unsigned timeout_ms, struct asph_error *err);

/* Reads exactly len bytes of a stream within timeout_ms in all. */
int transport_recv_exact(struct transport *t, void *buf, size_t len,
			 unsigned timeout_ms, struct asph_error *err);

/* Any thread: the waiting call and every later one return -ECANCELED. */
void transport_cancel(struct transport *t);

/* ms left until a deadline of CLOCK_MONOTONIC ns (0 when passed). */
uint64_t transport_deadline(unsigned timeout_ms);
unsigned transport_ms_left(uint64_t deadline);

#endif
