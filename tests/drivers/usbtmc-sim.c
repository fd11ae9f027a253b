/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A simulated USBTMC instrument speaking the default SCPI profile. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mock/protocol.h"
#include "usb/protocol.h"
#include "usbtmc-sim.h"

#define TRAVEL 50.0

const struct umu_usb_desc usbtmc_sim_desc = {
	.busnum = 1, .devnum = 5, .sysname = "1-3",
	.vendor = 0x1234, .product = 0x5678,
	.manufacturer = "ASPH", .product_name = "USBTMC probe", .serial = "SN4711",
	.if_class = 0xfe, .if_subclass = 0x03, .if_protocol = 0x01,
	.ep_in = 0x81, .ep_out = 0x02, .ep_intr = 0x83, .max_packet = 512,
};

void usbtmc_sim_fault(struct usbtmc_sim *s, enum usbtmc_sim_fault f, unsigned n)
{
	s->fault = f;
	s->fault_at = n;
}

static void push_error(struct usbtmc_sim *s, int code)
{
	if (s->n_errors < sizeof(s->errors) / sizeof(s->errors[0]))
		s->errors[s->n_errors++] = code;
}

static const char *error_text(int code)
{
	switch (code) {
	case -113: return "Undefined header";
	case -222: return "Data out of range";
	case -224: return "Illegal parameter value";
	default: return "Error";
	}
}

__attribute__((format(printf, 2, 3)))
static void answer(struct usbtmc_sim *s, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	s->reply_len = (size_t)vsnprintf(s->reply, sizeof(s->reply), fmt, ap);
	va_end(ap);
	s->reply_sent = 0;
	s->has_reply = true;
}

static void measure(struct usbtmc_sim *s)
{
	const volatile double *w = s->world_xyz ? s->world_xyz : s->pos;
	double z;

	if (!s->part || mock_part_probe_z(s->part, w[0], w[1], 0, &z) < 0)
		answer(s, "9.91E37\n");
	else
		answer(s, "%.17g\n", z - w[2]);
}

static void move(struct usbtmc_sim *s, const char *args)
{
	double t[3];
	char *end;

	for (int k = 0; k < 3; k++) {
		t[k] = strtod(args, &end);
		if (end == args || (k < 2 && *end != ',')) {
			push_error(s, -224);
			return;
		}
		args = end + 1;
	}
	for (int k = 0; k < 3; k++)
		if (!(fabs(t[k]) <= TRAVEL)) {
			push_error(s, -222);
			return;
		}
	memcpy(s->pos, t, sizeof(t));
	s->moving = 1;
}

/* One complete message (a line) from the host. */
static void execute(struct usbtmc_sim *s, char *line)
{
	line[strcspn(line, "\r\n")] = '\0';
	bool query = line[0] && line[strlen(line) - 1] == '?';

	s->n_queries += query;
	s->n_commands += !query;
	if (!strcmp(line, "*CLS")) {
		s->n_errors = 0;
	} else if (!strcmp(line, "*IDN?")) {
		answer(s, "ASPH,USBTMC-SIM,SN4711,1.0\n");
	} else if (!strcmp(line, "SYST:ERR?")) {
		if (s->n_errors) {
			int code = s->errors[0];
			memmove(s->errors, s->errors + 1, --s->n_errors * sizeof(int));
			answer(s, "%d,\"%s\"\n", code, error_text(code));
		} else {
			answer(s, "+0,\"No error\"\n");
		}
	} else if (!strcmp(line, "MEAS:DIST?") && s->part) {
		measure(s);
	} else if (!strncmp(line, "MOVE:ABS ", 9)) {
		move(s, line + 9);
	} else if (!strcmp(line, "HOME")) {
		memset(s->pos, 0, sizeof(s->pos));
		s->homed = true;
		s->moving = 1;
	} else if (!strcmp(line, "POS?")) {
		answer(s, "%.17g,%.17g,%.17g\n", s->pos[0], s->pos[1], s->pos[2]);
	} else if (!strcmp(line, "STAT?")) {
		int bits = (s->moving > 0) | (s->homed ? 2 : 0);
		if (s->moving > 0)
			s->moving--;
		answer(s, "%d\n", bits);
	} else {
		/* a refused query has no reply: only the error queue says why */
		push_error(s, -113);
	}
}

static uint32_t le32(const uint8_t *p)
{
	return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The host's bTag runs 1, 2, ... 255, 1, ... and bTagInverse is ~bTag. */
static void check_tag(struct usbtmc_sim *s, const uint8_t *h)
{
	if (h[1] != (uint8_t)(s->last_tag % 255 + 1) || (uint8_t)(h[1] ^ h[2]) != 0xff)
		s->n_tag_errors++;
	s->last_tag = h[1];
}

static int bulk_out(void *model, uint8_t ep, const uint8_t *buf, size_t len)
{
	struct usbtmc_sim *s = model;

	(void)ep;
	if (len < USBTMC_HEADER_SIZE || len % 4)
		return s->n_align_errors++, -EPIPE;
	/* retried at every reap while it hangs: decide once */
	if (s->out_stuck)
		return UMU_PENDING;
	if (s->fault == SIM_FAULT_STUCK_OUT && s->fault_at && !--s->fault_at) {
		s->fault = SIM_FAULT_NONE;
		s->out_stuck = true;
		s->out_stuck_tag = buf[1];
		check_tag(s, buf);
		return UMU_PENDING;
	}
	check_tag(s, buf);
	uint32_t n = le32(buf + 4);
	if (buf[0] == USBTMC_DEV_DEP_MSG_OUT) {
		if (len != usbtmc_padded(n) || s->msg_len + n >= sizeof(s->msg))
			return s->n_align_errors++, -EPIPE;
		memcpy(s->msg + s->msg_len, buf + USBTMC_HEADER_SIZE, n);
		s->msg_len += n;
		if (buf[8] & USBTMC_EOM) {
			s->msg[s->msg_len] = '\0';
			s->msg_len = 0;
			execute(s, s->msg);
		}
		return 0;
	}
	if (buf[0] == USBTMC_REQUEST_DEV_DEP_MSG_IN && len == USBTMC_HEADER_SIZE) {
		s->request = true;
		s->request_tag = buf[1];
		s->request_size = n;
		return 0;
	}
	return s->n_align_errors++, -EPIPE;
}

/* A fault armed for this reply, if it is the one. */
static enum usbtmc_sim_fault due(struct usbtmc_sim *s)
{
	if (!s->fault || !s->fault_at || s->reply_sent)
		return SIM_FAULT_NONE;
	if (--s->fault_at)
		return SIM_FAULT_NONE;
	enum usbtmc_sim_fault f = s->fault;
	s->fault = SIM_FAULT_NONE;
	return f;
}

static int bulk_in(void *model, uint8_t ep, uint8_t *buf, size_t len)
{
	struct usbtmc_sim *s = model;

	(void)ep;
	if (s->zlp) {
		s->zlp = false;
		return 0;
	}
	if (!s->request || !s->has_reply)
		return UMU_PENDING;
	enum usbtmc_sim_fault f = due(s);
	if (f == SIM_FAULT_SILENT)
		s->has_reply = false;
	if (f == SIM_FAULT_SILENT)
		return UMU_PENDING;
	if (f == SIM_FAULT_STALL_IN)
		return -EPIPE;
	if (f == SIM_FAULT_UNPLUG)
		return UMU_UNPLUGGED;
	size_t n = s->reply_len - s->reply_sent;
	size_t room = (len - USBTMC_HEADER_SIZE) & ~(size_t)3;
	if (n > s->request_size)
		n = s->request_size;
	if (n > room)
		n = room;
	if (s->max_chunk && n > s->max_chunk)
		n = s->max_chunk;
	bool eom = s->reply_sent + n == s->reply_len;
	usbtmc_header(buf, USBTMC_DEV_DEP_MSG_IN, f == SIM_FAULT_WRONG_TAG ? s->request_tag + 1
									 : s->request_tag,
		      (uint32_t)n, eom ? USBTMC_EOM : 0, 0);
	memcpy(buf + USBTMC_HEADER_SIZE, s->reply + s->reply_sent, n);
	size_t total = usbtmc_padded(n);
	memset(buf + USBTMC_HEADER_SIZE + n, 0, total - USBTMC_HEADER_SIZE - n);
	s->reply_sent += n;
	s->request = false;
	s->n_transfers_in++;
	if (eom)
		s->has_reply = false;
	if (f == SIM_FAULT_SHORT_READ)
		return USBTMC_HEADER_SIZE + (int)n / 2;
	return (int)total;
}

/* Status of a CHECK_* request: SUCCESS, nothing pending. */
static int status_reply(uint8_t *data, size_t len, size_t want)
{
	memset(data, 0, len);
	data[0] = USBTMC_STATUS_SUCCESS;
	return (int)(want < len ? want : len);
}

static int control(void *model, const uint8_t *setup, uint8_t *data, size_t len)
{
	struct usbtmc_sim *s = model;
	uint16_t value = (uint16_t)(setup[2] | setup[3] << 8);

	if (setup[0] == 0xa1 && setup[1] == USBTMC_INITIATE_CLEAR) {
		s->n_clear++;
		s->msg_len = 0;
		s->has_reply = s->request = false;
		return status_reply(data, len, 1);
	}
	if (setup[0] == 0xa1 && setup[1] == USBTMC_CHECK_CLEAR_STATUS)
		return status_reply(data, len, 2);
	if (setup[0] == 0xa2 && setup[1] == USBTMC_INITIATE_ABORT_BULK_IN) {
		s->n_abort_in++;
		bool running = s->request && s->request_tag == (uint8_t)value;
		s->request = false;
		s->has_reply = false;
		s->zlp = running;
		int n = status_reply(data, len, 2);
		data[0] = running ? USBTMC_STATUS_SUCCESS : USBTMC_STATUS_FAILED;
		if (len > 1)
			data[1] = (uint8_t)value;
		return n;
	}
	if (setup[0] == 0xa2 && setup[1] == USBTMC_CHECK_ABORT_BULK_IN_STATUS)
		return status_reply(data, len, 8);
	if (setup[0] == 0xa2 && setup[1] == USBTMC_INITIATE_ABORT_BULK_OUT) {
		s->n_abort_out++;
		bool running = s->out_stuck && s->out_stuck_tag == (uint8_t)value;
		s->out_stuck = false;
		s->msg_len = 0;
		int n = status_reply(data, len, 2);
		data[0] = running ? USBTMC_STATUS_SUCCESS : USBTMC_STATUS_FAILED;
		if (len > 1)
			data[1] = (uint8_t)value;
		return n;
	}
	if (setup[0] == 0xa2 && setup[1] == USBTMC_CHECK_ABORT_BULK_OUT_STATUS)
		return status_reply(data, len, 8);
	return -EPIPE;
}

/* A program's session starts its bTags at 1. */
static void claimed(void *model)
{
	struct usbtmc_sim *s = model;

	s->last_tag = 0;
}

const struct umu_usb_ops usbtmc_sim_ops = {
	.claimed = claimed,
	.control = control,
	.bulk_out = bulk_out,
	.bulk_in = bulk_in,
};
