/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Line-protocol stages and sensors: PI GCS, Newport, Aerotech, LinuxCNC,
 * Keyence, Sylvac, Mitutoyo and a lab's own devices, each
 * described by a profile file (profile.h), over TCP or a serial port.
 */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "asph/driver.h"
#include "drivers-config.h"
#include "fileio.h"
#include "link.h"
#include "profile.h"
#include "protocol.h"
#include "util-mem.h"

enum {
	OPT_PROFILE, OPT_HOST, OPT_PORT, OPT_DEVICE, OPT_BAUD, OPT_DATA_BITS, OPT_PARITY,
	OPT_STOP_BITS, OPT_RTSCTS, OPT_DTR, OPT_AXES, OPT_TIMEOUT, OPT_RECONNECT,
	OPT_TRAVEL_XY, OPT_TRAVEL_Z, OPT_SPEED,
	OPT_PROBE, OPT_TIP_RADIUS, OPT_STANDOFF, OPT_RANGE, OPT_RATE, OPT_SCALE, OPT_OFFSET,
	OPT_TRIGGER, OPT_DTR_MS,
	N_OPTIONS
};

static const char *const parities[] = { "profile", "none", "even", "odd", NULL };
static const char *const rtscts[] = { "profile", "on", "off", NULL };
static const char *const dtrs[] = { "on", "off", "leave", NULL };
static const char *const probe_types[] = { "optical", "tactile", NULL };
static const char *const triggers[] = { "request", "dtr", "operator", NULL };

#define P ASPH_ROLE_PROBE
#define S ASPH_ROLE_STAGE
#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)

static const struct asph_option_desc line_options[N_OPTIONS] = {
	[OPT_PROFILE] = { "profile", ASPH_OPTION_STRING, "pi-gcs",
			  .help = "the device's profile: a name (pi-gcs, newport-esp, aerotech-ascii, "
				  "linuxcnc, keyence-lk, sylvac, mitutoyo-vcp, or a "
				  "lab's own in " ASPH_LINE_PROFILE_ETC_DIR ") or a profile file's path" },
	[OPT_HOST] = { "host", ASPH_OPTION_STRING, "127.0.0.1",
		       .help = "TCP: the controller's host name or address (used when device is empty)" },
	[OPT_PORT] = { "port", ASPH_OPTION_INT, "50000", RANGE(1, 65535),
		       .help = "TCP port; unset, the profile's (pi-gcs: 50000)" },
	[OPT_DEVICE] = { "device", ASPH_OPTION_STRING, "",
			 .help = "serial port (e.g. /dev/ttyUSB0, /dev/ttyACM0); empty: TCP" },
	[OPT_BAUD] = { "baud", ASPH_OPTION_INT, "0", RANGE(0, 4000000), .unit = "bit/s",
		       .help = "serial: baud rate (0: the profile's)" },
	[OPT_DATA_BITS] = { "data_bits", ASPH_OPTION_INT, "0", RANGE(0, 8),
			    .help = "serial: data bits, 5 to 8 (0: the profile's)" },
	[OPT_PARITY] = { "parity", ASPH_OPTION_ENUM, "profile", .choices = parities,
			 .help = "serial: parity" },
	[OPT_STOP_BITS] = { "stop_bits", ASPH_OPTION_INT, "0", RANGE(0, 2),
			    .help = "serial: stop bits, 1 or 2 (0: the profile's)" },
	[OPT_RTSCTS] = { "rtscts", ASPH_OPTION_ENUM, "profile", .choices = rtscts,
			 .help = "serial: RTS/CTS hardware flow control" },
	[OPT_DTR] = { "dtr", ASPH_OPTION_ENUM, "on", .choices = dtrs,
		      .help = "serial: DTR while open (some cables draw power from it)" },
	[OPT_AXES] = { "axes", ASPH_OPTION_STRING, "",
		       .help = "a stage: the controller's axis ids for x, y, z, e.g. 1,2,3; a sensor: its "
			       "channel or head (empty: the profile's)" },
	[OPT_TIMEOUT] = { "timeout", ASPH_OPTION_INT, "1000", RANGE(1, 600000), .unit = "ms",
			  .help = "the longest wait for one reply" },
	[OPT_RECONNECT] = { "reconnect", ASPH_OPTION_BOOL, "true",
			    .help = "TCP: connect again after a lost connection (a lost move is never resumed)" },
	[OPT_TRAVEL_XY] = { "travel_xy", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			    .roles = S, .help = "x and y travel: -travel_xy .. travel_xy" },
	[OPT_TRAVEL_Z] = { "travel_z", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			   .roles = S, .help = "z travel: -travel_z .. travel_z" },
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "0", RANGE(0, 10000), .unit = "mm/s",
			.roles = S, .help = "velocity set on the controller (0: the controller's own)" },
	[OPT_PROBE] = { "probe", ASPH_OPTION_ENUM, "optical", .choices = probe_types, .roles = P,
			.help = "probe type" },
	[OPT_TIP_RADIUS] = { "tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0, 10), .unit = "mm",
			     .roles = P, .help = "tactile: tip ball radius" },
	[OPT_STANDOFF] = { "standoff", ASPH_OPTION_DOUBLE, "0", RANGE(-1e4, 1e4), .unit = "mm",
			   .roles = P, .help = "reading wanted on the nominal surface" },
	[OPT_RANGE] = { "range", ASPH_OPTION_DOUBLE, "1", RANGE(1e-6, 1e4), .unit = "mm",
			.roles = P, .help = "measuring range, centred on the standoff" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e6), .unit = "Hz", .roles = P,
		       .help = "readings per second (0: unknown)" },
	[OPT_SCALE] = { "scale", ASPH_OPTION_DOUBLE, "1", RANGE(-1e6, 1e6), .roles = P,
			.help = "reading = device value (in the profile's unit, as mm) x scale + offset; "
				"-1 when the value grows towards the probe" },
	[OPT_OFFSET] = { "offset", ASPH_OPTION_DOUBLE, "0", RANGE(-1e4, 1e4), .unit = "mm",
			 .roles = P, .help = "added to every reading" },
	[OPT_TRIGGER] = { "trigger", ASPH_OPTION_ENUM, "request", .choices = triggers, .roles = P,
			  .help = "how a reading comes: the profile's request, a DTR pulse, or the "
				  "operator (foot switch, data button) within the read timeout" },
	[OPT_DTR_MS] = { "dtr_ms", ASPH_OPTION_INT, "20", RANGE(1, 1000), .unit = "ms", .roles = P,
			 .help = "trigger=dtr: length of the DTR pulse" },
};

#undef RANGE

/* -------------------------------------------------------- the device */

struct asph_device {
	atomic_bool stop;
	pthread_mutex_t lock;           /* t against stop() while it is replaced */
	struct transport *t;            /* NULL while disconnected */
	struct line_link_params lp;
	char host[256], path[256];
	struct line_profile prof;
	struct line_reader rd;
	struct line_vars vars;
	char ids[3][16];
	unsigned reply_ms;
	bool reconnect, stage;
	/* stage */
	struct asph_stage_info info;
	bool homed;
	double speed;
	/* probe */
	struct asph_probe_info pinfo;
	double scale, offset;
	int trigger;
	unsigned dtr_ms;
};

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	transport_free(d->t);
	pthread_mutex_destroy(&d->lock);
	free(d);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_device *, dev_close)

/* ----------------------------------------------------------- profile */

static int load_file(const char *path, struct line_profile *p, struct asph_error *err)
{
	_cleanup_free_ char *text = NULL;
	size_t len = 0;
	int r = file_read_all(path, 1u << 20, &text, &len, err);

	return r < 0 ? r : line_profile_parse(text, len, path, p, err);
}

/* A path, else NAME.profile in $ASPH_LINE_PROFILE_PATH, the lab's
 * directory, the installed one. */
static int load_profile(const char *name, struct line_profile *p, struct asph_error *err)
{
	char path[512];
	const char *env = getenv("ASPH_LINE_PROFILE_PATH");
	char dirs[1024];

	if (strchr(name, '/'))
		return load_file(name, p, err);
	if (!*name || strlen(name) > 64)
		return asph_error_set(err, -EINVAL, "profile: give a profile name or a file's path");
	snprintf(dirs, sizeof(dirs), "%s%s" ASPH_LINE_PROFILE_ETC_DIR ":" ASPH_LINE_PROFILE_DIR,
		 env ? env : "", env && *env ? ":" : "");
	char *save = NULL;
	for (char *dir = strtok_r(dirs, ":", &save); dir; dir = strtok_r(NULL, ":", &save)) {
		snprintf(path, sizeof(path), "%s/%s.profile", dir, name);
		FILE *f = fopen(path, "r");
		if (!f)
			continue;
		fclose(f);
		return load_file(path, p, err);
	}
	asph_error_set(err, -ENOENT, "no line profile '%s' (looked in %s%s" ASPH_LINE_PROFILE_ETC_DIR
		       " and " ASPH_LINE_PROFILE_DIR ")", name, env ? env : "", env && *env ? ", " : "");
	asph_error_locate(err, NULL, 0, 0, "profile");
	return -ENOENT;
}

static int parse_axes(struct asph_device *d, const char *text, struct asph_error *err)
{
	char buf[64];
	int n = 0;

	for (int k = 0; k < 3; k++)
		memcpy(d->ids[k], d->prof.axes[k], sizeof(d->ids[k]));
	if (!*text)
		return 0;
	snprintf(buf, sizeof(buf), "%s", text);
	char *save = NULL;
	for (char *id = strtok_r(buf, ",", &save); id; id = strtok_r(NULL, ",", &save), n++) {
		if (n == 3 || strlen(id) >= sizeof(d->ids[0]) || strpbrk(id, " {}\\")) {
			n = -1;
			break;
		}
		snprintf(d->ids[n], sizeof(d->ids[n]), "%s", id);
	}
	if (d->stage ? n != 3 : n < 1) {
		asph_error_set(err, -EINVAL, "option 'axes': %s separated by commas (e.g. %s), not '%s'",
			       d->stage ? "three axis ids for x, y, z" : "the sensor's channel first",
			       d->stage ? "1,2,3" : "1", text);
		asph_error_locate(err, NULL, 0, 0, "axes");
		return -EINVAL;
	}
	return 0;
}

/* ------------------------------------------------------- connections */

static int connect_link(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	struct transport *t = NULL;
	int r = line_link_open(&d->lp, timeout_ms, &t, err);

	if (r < 0)
		return r;
	pthread_mutex_lock(&d->lock);
	d->t = t;
	line_reader_clear(&d->rd);
	/* a stop() that came while connecting still counts */
	if (atomic_load(&d->stop))
		transport_cancel(t);
	pthread_mutex_unlock(&d->lock);
	return 0;
}

static void drop_link(struct asph_device *d)
{
	pthread_mutex_lock(&d->lock);
	transport_free(d->t);
	d->t = NULL;
	pthread_mutex_unlock(&d->lock);
}

static const char *link_name(const struct asph_device *d, char *buf, size_t size)
{
	if (d->lp.serial)
		snprintf(buf, size, "%s", d->lp.device);
	else
		snprintf(buf, size, "%s:%d", d->lp.host, d->lp.port);
	return buf;
}

/* ---------------------------------------------------------- dialogue */

static int send_line(struct asph_device *d, const char *cmd, uint64_t deadline,
		     struct asph_error *err)
{
	char buf[LINE_REPLY_MAX];
	/* a single control character (GCS #5, #7, #24) goes alone */
	bool alone = cmd[0] && !cmd[1] && (unsigned char)cmd[0] < 0x20;
	int n = snprintf(buf, sizeof(buf), "%s%s", cmd, alone ? "" : d->prof.send_terminator);

	if (!d->t)
		return asph_error_set(err, -ENODEV, "not connected");
	if (n < 0 || (size_t)n >= sizeof(buf))
		return asph_error_set(err, -EINVAL, "command too long");
	/* what came unasked (a late reply to an abandoned command) is not
	 * the answer to this one */
	line_reader_clear(&d->rd);
	return transport_send(d->t, buf, (size_t)n, transport_ms_left(deadline), err);
}

/* The next reply, within the reply timeout and the deadline. what names
 * the command in messages. */
static int read_reply(struct asph_device *d, const char *what, char *out, size_t size,
		      uint64_t deadline, unsigned limit_ms, struct asph_error *err)
{
	uint64_t reply_deadline = transport_deadline(limit_ms);
	char shown[160], name[300];

	if (reply_deadline > deadline)
		reply_deadline = deadline;
	for (;;) {
		int r = line_reader_take(&d->rd, d->prof.reply_terminator, d->prof.continuation, out,
					 size, err);
		if (r != 0)
			return r < 0 ? r : 0;
		char buf[512];
		size_t got = 0;
		r = transport_recv(d->t, buf, sizeof(buf), &got, transport_ms_left(reply_deadline), err);
		if (r == -ETIMEDOUT) {
			line_reader_pending(&d->rd, shown, sizeof(shown));
			link_name(d, name, sizeof(name));
			if (d->rd.len)
				return asph_error_set(err, -EPROTO, "%s: partial reply '%s' to '%s' "
						      "(no line end within %u ms)", name, shown, what,
						      limit_ms);
			return asph_error_set(err, -ETIMEDOUT, "%s: no reply to '%s' within %u ms",
					      name, what, limit_ms);
		}
		if (r < 0)
			return r;
		r = line_reader_add(&d->rd, buf, got, err);
		if (r < 0)
			return r;
	}
}

/* Formats a device error with the profile's error_format. */
static int device_error(struct asph_device *d, long code, bool has_code, const char *text,
			struct asph_error *err)
{
	const char *f = d->prof.error_format[0] ? d->prof.error_format : "device error {code}: {text}";
	char msg[256], table[160] = "";
	size_t o = 0;

	if (has_code)
		line_profile_error_text(&d->prof, code, table, sizeof(table));
	if (!*text)
		text = *table ? table : "(no text for this code in the profile)";
	for (const char *c = f; *c && o + 1 < sizeof(msg); c++) {
		int n = 0;
		if (!strncmp(c, "{code}", 6)) {
			n = has_code ? snprintf(msg + o, sizeof(msg) - o, "%ld", code)
				     : snprintf(msg + o, sizeof(msg) - o, "?");
			c += 5;
		} else if (!strncmp(c, "{text}", 6)) {
			n = snprintf(msg + o, sizeof(msg) - o, "%s", text);
			c += 5;
		} else {
			msg[o] = *c;
			n = 1;
		}
		o += n > 0 ? (size_t)n : 0;
		if (o >= sizeof(msg))
			o = sizeof(msg) - 1;
	}
	msg[o] = '\0';
	return asph_error_set(err, -EPROTO, "%s", msg);
}

static int run_error_query(struct asph_device *d, uint64_t deadline, bool *clean,
			   struct asph_error *err);

/* A reply that is one of the profile's error replies ends the operation
 * with the device's text. 1 when it was one. */
static int error_reply(struct asph_device *d, const char *reply, uint64_t deadline,
		       struct asph_error *err)
{
	for (unsigned i = 0; i < d->prof.n_error_replies; i++) {
		const struct line_error_reply *er = &d->prof.error_replies[i];
		struct line_match m;
		memset(&m, 0, sizeof(m));
		if (!line_match(er->pattern, reply, &d->vars, &m))
			continue;
		if (!er->text[0] && !m.has_code && !m.has_text && d->prof.error_query[0]) {
			bool clean = true;
			int r = run_error_query(d, deadline, &clean, err);
			if (r < 0 || !clean)
				return r < 0 ? r : -EPROTO;
		}
		char shown[160];
		line_printable(reply, shown, sizeof(shown));
		if (er->text[0] && !m.has_code)
			return device_error(d, 0, false, er->text, err);
		return device_error(d, m.code, m.has_code, m.has_text ? m.text : er->text, err);
	}
	return 0;
}

static int unexpected(struct asph_device *d, const char *cmd, const char *reply,
		      const char *pattern, struct asph_error *err)
{
	char shown[160], pat[160], sent[160];

	line_printable(reply, shown, sizeof(shown));
	line_printable(pattern, pat, sizeof(pat));
	line_printable(cmd, sent, sizeof(sent));
	return asph_error_set(err, -EPROTO, "unexpected reply '%s' to '%s' (expected %s): a "
			      "garbled line or the answer to another command", shown, sent, pat);
}

/* Sends cmd and matches its reply against pattern (and range, an
 * out-of-range reading). */
static int query(struct asph_device *d, const char *cmd, const char *pattern, const char *range,
		 struct line_match *m, bool *out_of_range, uint64_t deadline,
		 struct asph_error *err)
{
	char reply[LINE_REPLY_MAX];
	int r = cmd ? send_line(d, cmd, deadline, err) : 0;

	if (r == 0)
		r = read_reply(d, cmd ? cmd : "(a reading: the gauge's data button or foot switch)",
			       reply, sizeof(reply), deadline,
			       cmd ? d->reply_ms : transport_ms_left(deadline), err);
	if (r < 0)
		return r;
	if (line_match(pattern, reply, &d->vars, m))
		return 0;
	if (range && *range && line_match(range, reply, &d->vars, m)) {
		*out_of_range = true;
		return 0;
	}
	r = error_reply(d, reply, deadline, err);
	return r < 0 ? r : unexpected(d, cmd ? cmd : "(a reading)", reply, pattern, err);
}

static int run_error_query(struct asph_device *d, uint64_t deadline, bool *clean,
			   struct asph_error *err)
{
	struct line_match m;
	bool oor = false;

	char cmd[LINE_REPLY_MAX / 2];

	memset(&m, 0, sizeof(m));
	*clean = true;
	int r = line_expand(d->prof.error_query, &d->vars, cmd, sizeof(cmd), err);
	if (r == 0)
		r = query(d, cmd, d->prof.error_reply_pattern, NULL, &m, &oor, deadline, err);
	if (r < 0)
		return r;
	if (m.has_code ? m.code == d->prof.error_none : !strcmp(m.text, d->prof.error_none_text))
		return 0;
	*clean = false;
	return device_error(d, m.code, m.has_code, m.has_text ? m.text : "", err);
}

static int nap(struct asph_device *d, unsigned ms, uint64_t deadline, struct asph_error *err)
{
	unsigned left = transport_ms_left(deadline);
	struct timespec ts;

	if (ms > left)
		ms = left;
	ts = (struct timespec){ ms / 1000, (long)(ms % 1000) * 1000000 };
	nanosleep(&ts, NULL);
	return atomic_load(&d->stop) ? asph_error_set(err, -ECANCELED, "stopped") : 0;
}

static int wait_step(struct asph_device *d, const struct line_step *st, const char *cmd,
		     struct line_match *m, uint64_t deadline, unsigned timeout_ms,
		     struct asph_error *err)
{
	char reply[LINE_REPLY_MAX], shown[160];

	for (;;) {
		int r = send_line(d, cmd, deadline, err);
		if (r == 0)
			r = read_reply(d, cmd, reply, sizeof(reply), deadline, d->reply_ms, err);
		if (r < 0)
			return r;
		struct line_match b;
		memset(&b, 0, sizeof(b));
		bool matched = line_match(st->reply, reply, &d->vars, &b);
		if (matched && (!st->has_mask || (b.code & st->mask) == st->value)) {
			line_match(st->reply, reply, &d->vars, m);
			return 0;
		}
		bool busy = matched;
		for (unsigned i = 0; i < st->n_busy && !busy; i++)
			busy = line_match(st->busy[i], reply, &d->vars, &b);
		if (!busy) {
			r = error_reply(d, reply, deadline, err);
			return r < 0 ? r : unexpected(d, cmd, reply, st->reply, err);
		}
		if (transport_ms_left(deadline) == 0) {
			line_printable(reply, shown, sizeof(shown));
			return asph_error_set(err, -ETIMEDOUT, "'%s' still answered '%s' after %u ms",
					      cmd, shown, timeout_ms);
		}
		r = nap(d, d->prof.poll_ms, deadline, err);
		if (r < 0)
			return r;
	}
}

static int run_step(struct asph_device *d, const struct line_step *st, struct line_match *m,
		    bool *oor, uint64_t deadline, unsigned timeout_ms, struct asph_error *err)
{
	char cmd[LINE_REPLY_MAX / 2], reply[LINE_REPLY_MAX];
	bool clean;
	int r = 0;

	if (st->kind == LINE_STEP_SEND || st->kind == LINE_STEP_QUERY || st->kind == LINE_STEP_WAIT)
		r = line_expand(st->command, &d->vars, cmd, sizeof(cmd), err);
	if (r < 0)
		return r;
	switch (st->kind) {
	case LINE_STEP_SEND: {
		const char *ack = st->ack[0] ? st->ack : d->prof.ack;
		r = send_line(d, cmd, deadline, err);
		if (r < 0 || !*ack)
			return r;
		r = read_reply(d, cmd, reply, sizeof(reply), deadline, d->reply_ms, err);
		if (r < 0 || line_match(ack, reply, &d->vars, m))
			return r;
		r = error_reply(d, reply, deadline, err);
		return r < 0 ? r : unexpected(d, cmd, reply, ack, err);
	}
	case LINE_STEP_QUERY:
		return query(d, cmd, st->reply, st->range, m, oor, deadline, err);
	case LINE_STEP_READ:
		return query(d, NULL, st->reply, st->range, m, oor, deadline, err);
	case LINE_STEP_WAIT:
		return wait_step(d, st, cmd, m, deadline, timeout_ms, err);
	case LINE_STEP_CHECK:
		return run_error_query(d, deadline, &clean, err);
	case LINE_STEP_DELAY:
		return nap(d, st->ms, deadline, err);
	case LINE_STEP_DTR:
		return line_link_dtr_pulse(d->t, st->ms, err);
	}
	return asph_error_set(err, -EINVAL, "unknown step");
}

/* Runs an operation of the profile; steps that name an axis run for each
 * of the axes of mask in turn. */
static int run_op(struct asph_device *d, enum line_op_id id, unsigned mask, struct line_match *m,
		  bool *oor, uint64_t deadline, unsigned timeout_ms, struct asph_error *err)
{
	const struct line_op *op = &d->prof.ops[id];

	if (atomic_load(&d->stop))
		return asph_error_set(err, -ECANCELED, "stopped");
	if (!d->t)
		return asph_error_set(err, -ENODEV, "not connected");
	for (unsigned i = 0; i < op->n; i++) {
		const struct line_step *st = &op->steps[i];
		for (int k = 0; k < 3; k++) {
			if (st->per_axis && !(mask >> k & 1))
				continue;
			d->vars.axis = st->per_axis ? k : -1;
			int r = run_step(d, st, m, oor, deadline, timeout_ms, err);
			if (r < 0) {
				char msg[sizeof(err->message)];
				if (!err)
					return r;
				snprintf(msg, sizeof(msg), "%s", err->message);
				if (st->per_axis && r != -ECANCELED)
					return asph_error_set(err, r, "axis %s (%s): %s: %s",
							      d->info.axes[k].name[0] ? d->info.axes[k].name : "?",
							      d->ids[k], line_op_name(id), msg);
				return asph_error_set(err, r, "%s: %s", line_op_name(id), msg);
			}
			if (!st->per_axis)
				break;
		}
	}
	return 0;
}

/* The stop operation without the transport's waits: after stop() has
 * cancelled it, or on a connection just made to stop a stage. */
static void send_stop(struct asph_device *d)
{
	const struct line_op *op = &d->prof.ops[LINE_OP_STOP];
	char cmd[LINE_REPLY_MAX / 2], line[LINE_REPLY_MAX];

	pthread_mutex_lock(&d->lock);
	for (unsigned i = 0; d->t && i < op->n; i++) {
		const struct line_step *st = &op->steps[i];
		if (st->kind != LINE_STEP_SEND && st->kind != LINE_STEP_QUERY)
			continue;
		for (int k = 0; k < 3; k++) {
			d->vars.axis = st->per_axis ? k : -1;
			if (line_expand(st->command, &d->vars, cmd, sizeof(cmd), NULL) == 0) {
				bool alone = cmd[0] && !cmd[1] && (unsigned char)cmd[0] < 0x20;
				int n = snprintf(line, sizeof(line), "%s%s", cmd,
						 alone ? "" : d->prof.send_terminator);
				if (n > 0 && (size_t)n < sizeof(line))
					line_link_send_raw(d->t, line, (size_t)n, 200);
			}
			if (!st->per_axis)
				break;
		}
	}
	pthread_mutex_unlock(&d->lock);
}

/* Connects again after a lost TCP connection and says hello. */
static int reconnect(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	struct line_match m;
	bool oor = false;

	drop_link(d);
	if (d->lp.serial || !d->reconnect)
		return asph_error_set(err, -ENODEV, "the connection is lost");
	int r = connect_link(d, timeout_ms, err);
	uint64_t deadline = transport_deadline(timeout_ms);
	memset(&m, 0, sizeof(m));
	if (r == 0 && d->prof.ops[LINE_OP_CONNECT].defined)
		r = run_op(d, LINE_OP_CONNECT, 7, &m, &oor, deadline, timeout_ms, err);
	if (r < 0)
		drop_link(d);
	return r;
}

/*
 * Ends a stage operation. A stop() made the transport refuse: the stop
 * command goes out directly. A lost connection is made again (TCP) to
 * stop the stage; a device error or a bad reply stops it too.
 */
static int finish(struct asph_device *d, int r, struct asph_error *err)
{
	struct asph_error e;

	if (r >= 0 || !d->stage)
		return r;
	if (r == -ENODEV) {
		if (reconnect(d, d->reply_ms, &e) == 0) {
			send_stop(d);
			if (err) {
				char msg[sizeof(err->message)];
				snprintf(msg, sizeof(msg), "%s", err->message);
				asph_error_set(err, r, "%s; connected again and stopped the stage", msg);
			}
		} else if (err) {
			char msg[sizeof(err->message)];
			snprintf(msg, sizeof(msg), "%s", err->message);
			asph_error_set(err, r, "%s; could not connect again to stop the stage (%s)", msg,
				       e.message);
		}
		return r;
	}
	send_stop(d);
	return r;
}

/* Before an operation: a connection lost earlier is made again. */
static int ready(struct asph_device *d, struct asph_error *err)
{
	if (atomic_load(&d->stop))
		return asph_error_set(err, -ECANCELED, "stopped");
	return d->t ? 0 : reconnect(d, d->reply_ms, err);
}

/* ------------------------------------------------------------ common */

static int dev_open(const struct asph_option_value *o, bool stage, unsigned timeout_ms,
		    struct asph_device **out, struct asph_error *err)
{
	_cleanup_(dev_closep) struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	atomic_init(&d->stop, false);
	pthread_mutex_init(&d->lock, NULL);
	d->stage = stage;
	int r = load_profile(o[OPT_PROFILE].s, &d->prof, err);
	if (r < 0)
		return r;
	unsigned role = stage ? LINE_ROLE_STAGE : LINE_ROLE_PROBE;
	if (!(d->prof.roles & role)) {
		asph_error_set(err, -EINVAL, "profile '%s' describes a %s, not a %s", d->prof.name,
			       stage ? "probe" : "stage", stage ? "stage" : "probe");
		asph_error_locate(err, NULL, 0, 0, "profile");
		return -EINVAL;
	}
	r = parse_axes(d, o[OPT_AXES].s, err);
	if (r < 0)
		return r;
	snprintf(d->host, sizeof(d->host), "%s", o[OPT_HOST].s);
	snprintf(d->path, sizeof(d->path), "%s", o[OPT_DEVICE].s);
	d->lp = (struct line_link_params){
		.serial = *d->path != '\0', .host = d->host, .device = d->path,
		.port = o[OPT_PORT].set || !d->prof.tcp_port ? (int)o[OPT_PORT].i : d->prof.tcp_port,
		.baud = o[OPT_BAUD].i ? (int)o[OPT_BAUD].i : d->prof.baud,
		.data_bits = o[OPT_DATA_BITS].i ? (int)o[OPT_DATA_BITS].i : d->prof.data_bits,
		.stop_bits = o[OPT_STOP_BITS].i ? (int)o[OPT_STOP_BITS].i : d->prof.stop_bits,
		.parity = o[OPT_PARITY].i == 0 ? d->prof.parity : "NNEO"[o[OPT_PARITY].i],
		.rtscts = o[OPT_RTSCTS].i == 0 ? d->prof.rtscts : o[OPT_RTSCTS].i == 1,
		.dtr = o[OPT_DTR].i == 0 ? 1 : o[OPT_DTR].i == 1 ? 0 : -1,
	};
	if (d->lp.data_bits < 5) {
		asph_error_set(err, -ERANGE, "option 'data_bits': 5 to 8");
		asph_error_locate(err, NULL, 0, 0, "data_bits");
		return -ERANGE;
	}
	for (int k = 0; k < 3; k++)
		d->vars.axis_ids[k] = d->ids[k];
	d->vars.axis = -1;
	d->vars.decimals = d->prof.decimals;
	d->reply_ms = (unsigned)o[OPT_TIMEOUT].i;
	d->reconnect = o[OPT_RECONNECT].b;
	r = connect_link(d, timeout_ms, err);
	if (r < 0)
		return r;
	struct line_match m;
	bool oor = false;
	memset(&m, 0, sizeof(m));
	uint64_t deadline = transport_deadline(timeout_ms);
	if (d->prof.ops[LINE_OP_CONNECT].defined)
		r = run_op(d, LINE_OP_CONNECT, 7, &m, &oor, deadline, timeout_ms, err);
	if (r < 0)
		return r;
	*out = steal_ptr(d);
	return 0;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	pthread_mutex_lock(&d->lock);
	if (d->t)
		transport_cancel(d->t);
	pthread_mutex_unlock(&d->lock);
	return 0;
}

/* ------------------------------------------------------------- stage */

static void axis(struct asph_axis_info *a, const char *name, double travel, double speed)
{
	snprintf(a->name, sizeof(a->name), "%s", name);
	snprintf(a->unit, sizeof(a->unit), "mm");
	a->min = -travel;
	a->max = travel;
	a->max_speed = speed;
}

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = NULL;
	int r = dev_open(o, true, timeout_ms, &d, err);

	if (r < 0)
		return r;
	d->speed = o[OPT_SPEED].d;
	d->info.kinematics = ASPH_KINEMATICS_XYZ;
	d->info.n_axes = 3;
	axis(&d->info.axes[0], "x", o[OPT_TRAVEL_XY].d, d->speed);
	axis(&d->info.axes[1], "y", o[OPT_TRAVEL_XY].d, d->speed);
	axis(&d->info.axes[2], "z", o[OPT_TRAVEL_Z].d, d->speed);
	snprintf(d->info.model, sizeof(d->info.model), "%.63s", d->prof.description[0]
		 ? d->prof.description : d->prof.name);
	link_name(d, d->info.serial, sizeof(d->info.serial));
	struct line_match m;
	bool oor = false;
	memset(&m, 0, sizeof(m));
	uint64_t deadline = transport_deadline(timeout_ms);
	d->vars.speed = d->speed / d->prof.unit_mm;
	if (d->prof.ops[LINE_OP_ENABLE].defined)
		r = run_op(d, LINE_OP_ENABLE, 7, &m, &oor, deadline, timeout_ms, err);
	if (r == 0 && d->speed > 0 && d->prof.ops[LINE_OP_VELOCITY].defined)
		r = run_op(d, LINE_OP_VELOCITY, 7, &m, &oor, deadline, timeout_ms, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out, struct asph_error *err)
{
	*out = d->info;
	return 0;
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	struct line_match m;
	bool oor = false;
	int r = ready(d, err);

	memset(&m, 0, sizeof(m));
	d->homed = false;
	if (r == 0)
		r = run_op(d, LINE_OP_HOME, 7, &m, &oor, transport_deadline(timeout_ms), timeout_ms, err);
	d->homed = r == 0;
	return finish(d, r, err);
}

static int stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		      struct asph_error *err)
{
	struct line_match m;
	bool oor = false;
	int r = ready(d, err);

	if (r < 0)
		return r;
	if (!d->homed)
		return asph_error_set(err, -EPROTO, "stage is not homed");
	for (int k = 0; k < 3; k++) {
		const struct asph_axis_info *a = &d->info.axes[k];
		if (!(t[k] >= a->min && t[k] <= a->max))
			return asph_error_set(err, -ERANGE, "axis %s: target %.6f mm is outside "
					      "%.6g .. %.6g", a->name, t[k], a->min, a->max);
		d->vars.target[k] = t[k] / d->prof.unit_mm;
	}
	memset(&m, 0, sizeof(m));
	r = run_op(d, LINE_OP_MOVE, 7, &m, &oor, transport_deadline(timeout_ms), timeout_ms, err);
	return finish(d, r, err);
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	struct line_match m;
	bool oor = false;
	int r = ready(d, err);

	memset(&m, 0, sizeof(m));
	if (r == 0)
		r = run_op(d, LINE_OP_POSITION, 7, &m, &oor, transport_deadline(timeout_ms),
			   timeout_ms, err);
	for (int k = 0; r == 0 && k < 3; k++) {
		if (!m.has_pos[k])
			return asph_error_set(err, -EPROTO, "position: no position of axis %s in the "
					      "replies", d->info.axes[k].name);
		/* read back from the controller, not the target */
		pos[k] = m.pos[k] * d->prof.unit_mm;
	}
	return r < 0 ? finish(d, r, err) : 0;
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	struct asph_error e;

	memset(out, 0, sizeof(*out));
	out->homed = d->homed;
	int r = stage_position(d, out->position, timeout_ms, &e);
	if (r == -ENODEV) {
		out->state = ASPH_STAGE_DISCONNECTED;
		snprintf(out->detail, sizeof(out->detail), "%.127s", e.message);
		return 0;
	}
	if (r == -EPROTO) {
		out->state = ASPH_STAGE_FAULT;
		snprintf(out->detail, sizeof(out->detail), "%.127s", e.message);
		return 0;
	}
	if (r < 0) {
		asph_error_set(err, r, "%s", e.message);
		return r;
	}
	out->state = d->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	return 0;
}

/* ------------------------------------------------------------- probe */

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = NULL;
	int r = dev_open(o, false, timeout_ms, &d, err);

	if (r < 0)
		return r;
	bool tactile = o[OPT_PROBE].i == 1;
	struct asph_probe_info *pi = &d->pinfo;
	pi->type = tactile ? ASPH_PROBE_TACTILE : ASPH_PROBE_OPTICAL;
	pi->tip_radius = tactile ? o[OPT_TIP_RADIUS].d : 0;
	pi->standoff = o[OPT_STANDOFF].d;
	pi->range_min = pi->standoff - o[OPT_RANGE].d / 2;
	pi->range_max = pi->standoff + o[OPT_RANGE].d / 2;
	pi->rate = o[OPT_RATE].d;
	snprintf(pi->model, sizeof(pi->model), "%.63s", d->prof.description[0]
		 ? d->prof.description : d->prof.name);
	link_name(d, pi->serial, sizeof(pi->serial));
	d->scale = o[OPT_SCALE].d;
	d->offset = o[OPT_OFFSET].d;
	d->trigger = (int)o[OPT_TRIGGER].i;
	d->dtr_ms = (unsigned)o[OPT_DTR_MS].i;
	*out = d;
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out, struct asph_error *err)
{
	*out = d->pinfo;
	return 0;
}

static uint64_t now_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* The reply patterns of the read operation's last query or read step:
 * what a DTR pulse or the operator's button brings. */
static const struct line_step *reading_step(const struct asph_device *d)
{
	const struct line_op *op = &d->prof.ops[LINE_OP_READ];

	for (unsigned i = op->n; i-- > 0;)
		if (op->steps[i].kind == LINE_STEP_QUERY || op->steps[i].kind == LINE_STEP_READ)
			return &op->steps[i];
	return NULL;
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	struct line_match m;
	bool oor = false;
	uint64_t deadline = transport_deadline(timeout_ms);
	const struct line_step *st = reading_step(d);
	int r = ready(d, err);

	memset(out, 0, sizeof(*out));
	memset(&m, 0, sizeof(m));
	if (r < 0)
		return r;
	if (d->trigger == 0) {
		r = run_op(d, LINE_OP_READ, 7, &m, &oor, deadline, timeout_ms, err);
	} else {
		if (d->trigger == 1)
			r = line_link_dtr_pulse(d->t, d->dtr_ms, err);
		else
			line_reader_clear(&d->rd);
		if (r == 0 && st)
			r = query(d, NULL, st->reply, st->range, &m, &oor, deadline, err);
	}
	if (r == -ENODEV)
		drop_link(d);
	if (r < 0)
		return r;
	out->t_ns = now_ns();
	if (oor || !m.has_value) {
		out->value = out->raw = NAN;
		out->flags = ASPH_READING_OUT_OF_RANGE;
		return 0;
	}
	out->raw = m.value;
	out->value = m.value * d->prof.unit_mm * d->scale + d->offset;
	if (!(out->value >= d->pinfo.range_min && out->value <= d->pinfo.range_max))
		out->flags = ASPH_READING_OUT_OF_RANGE;
	return 0;
}

static const struct asph_stage_ops line_stage = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = stage_home,
	.move_to = stage_move,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
};

static const struct asph_probe_ops line_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stop = dev_stop,
};

const struct asph_driver line_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "line",
	.description = "ASCII line-protocol stages and sensors over TCP or a serial port, "
		       "described by profiles (PI GCS, Newport, Aerotech, LinuxCNC, Keyence, "
		       "Sylvac, Mitutoyo)",
	.version = "1.0",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = line_options,
	.n_options = N_OPTIONS,
	.stage = &line_stage,
	.probe = &line_probe,
};
