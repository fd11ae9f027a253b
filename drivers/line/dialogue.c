/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A line device's dialogue (dialogue.h). */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "dialogue.h"
#include "util-time.h"

/* Tries of opening a serial port that went away, while it comes back. */
#define REOPEN_POLL_MS 20

/* ------------------------------------------------------- connections */

const char *line_dev_name(const struct asph_device *d, char *buf, size_t size)
{
	if (d->lp.serial)
		snprintf(buf, size, "%s", d->lp.device);
	else
		snprintf(buf, size, "%s:%d", d->lp.host, d->lp.port);
	return buf;
}

int line_dev_connect(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	struct transport *t = NULL;
	int r = line_link_open(&d->lp, timeout_ms, &t, err);

	if (r < 0)
		return r;
	pthread_mutex_lock(&d->lock);
	d->t = t;
	line_reader_clear(&d->rd);
	/* a stop() that came while connecting still counts */
	if (atomic_load(&d->stop) && !d->stopping)
		transport_cancel(t);
	pthread_mutex_unlock(&d->lock);
	return 0;
}

void line_dev_drop(struct asph_device *d)
{
	pthread_mutex_lock(&d->lock);
	transport_free(d->t);
	d->t = NULL;
	pthread_mutex_unlock(&d->lock);
}

/* A lost link made again within reconnect_ms: TCP connects; a serial port
 * is opened again as soon as its device is back (a USB adapter that
 * re-enumerates after a glitch or a replug), polled while it is not. */
static int relink(struct asph_device *d, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(d->reconnect_ms);
	int r;

	line_dev_drop(d);
	if (!d->reconnect)
		return asph_error_set(err, -ENODEV, "the connection is lost (reconnect is off)");
	for (;;) {
		r = line_dev_connect(d, transport_ms_left(deadline), err);
		if (r == 0 || r == -EACCES || !d->lp.serial || transport_ms_left(deadline) == 0)
			break;
		msleep(REOPEN_POLL_MS);
	}
	if (r < 0)
		return r;
	struct line_match m;
	bool oor = false;
	memset(&m, 0, sizeof(m));
	if (d->prof.ops[LINE_OP_CONNECT].defined)
		r = line_run_op(d, LINE_OP_CONNECT, 7, &m, &oor, transport_deadline(d->reply_ms),
				d->reply_ms, err);
	if (r < 0)
		line_dev_drop(d);
	return r;
}

int line_dev_ready(struct asph_device *d, struct asph_error *err)
{
	if (atomic_load(&d->stop))
		return asph_error_set(err, -ECANCELED, "stopped");
	return d->t ? 0 : relink(d, err);
}

/* ---------------------------------------------------------- dialogue */

static bool single_control_byte(const char *cmd)
{
	/* a single control character (GCS #5, #7, #24) goes alone */
	return cmd[0] && !cmd[1] && (unsigned char)cmd[0] < 0x20;
}

static int send_line(struct asph_device *d, const char *cmd, uint64_t deadline,
		     struct asph_error *err)
{
	char buf[LINE_REPLY_MAX];
	int n = snprintf(buf, sizeof(buf), "%s%s", cmd,
			 single_control_byte(cmd) ? "" : d->prof.send_terminator);

	if (!d->t)
		return asph_error_set(err, -ENODEV, "not connected");
	if (n < 0 || (size_t)n >= sizeof(buf))
		return asph_error_set(err, -EINVAL, "command too long");
	/* what came unasked (a late reply to an abandoned command) is not
	 * the answer to this one */
	line_reader_clear(&d->rd);
	return transport_send(d->t, buf, (size_t)n, transport_ms_left(deadline), err);
}

/* The next reply, within limit_ms and the deadline. what names the
 * command in messages. */
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
			line_dev_name(d, name, sizeof(name));
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

/* The device's error in the profile's error_format; text, else the
 * table's text of the code. */
static int device_error(struct asph_device *d, long code, bool has_code, const char *text,
			struct asph_error *err)
{
	const char *f = d->prof.error_format[0] ? d->prof.error_format : "device error {code}: {text}";
	char msg[256], table[160] = "", num[24] = "?";
	size_t o = 0;

	if (has_code) {
		line_profile_error_text(&d->prof, code, table, sizeof(table));
		snprintf(num, sizeof(num), "%ld", code);
	}
	if (!*text)
		text = *table ? table : "(no text for this code in the profile)";
	for (const char *c = f; *c && o + 1 < sizeof(msg);) {
		const char *part = !strncmp(c, "{code}", 6) ? num : !strncmp(c, "{text}", 6) ? text : NULL;
		int n = part ? snprintf(msg + o, sizeof(msg) - o, "%s", part) : (msg[o] = *c, 1);
		c += part ? 6 : 1;
		o = o + (size_t)n < sizeof(msg) ? o + (size_t)n : sizeof(msg) - 1;
	}
	msg[o] = '\0';
	return asph_error_set(err, -EPROTO, "%s", msg);
}

static int run_error_query(struct asph_device *d, uint64_t deadline, struct asph_error *err);

/* A reply that is one of the profile's error replies ends the operation
 * with the device's text; 0 when it is none. */
static int error_reply(struct asph_device *d, const char *reply, uint64_t deadline,
		       struct asph_error *err)
{
	for (unsigned i = 0; i < d->prof.n_error_replies; i++) {
		const struct line_error_reply *er = &d->prof.error_replies[i];
		struct line_match m;
		memset(&m, 0, sizeof(m));
		if (!line_match(er->pattern, reply, &d->vars, &m))
			continue;
		/* neither code nor text: the error query says what it is */
		if (!er->text[0] && !m.has_code && !m.has_text && d->prof.error_query[0]) {
			char shown[160];
			int r = run_error_query(d, deadline, err);
			if (r < 0)
				return r;
			line_printable(reply, shown, sizeof(shown));
			return asph_error_set(err, -EPROTO, "the device answered '%s', an error, and "
					      "its error query reports none", shown);
		}
		/* a reply whose meaning the profile spells out is its message */
		if (er->text[0] && !m.has_code)
			return asph_error_set(err, -EPROTO, "%s", er->text);
		return device_error(d, m.code, m.has_code, m.has_text ? m.text : er->text, err);
	}
	return 0;
}

static int unexpected(const char *cmd, const char *reply, const char *pattern,
		      struct asph_error *err)
{
	char shown[160], pat[160], sent[160];

	line_printable(reply, shown, sizeof(shown));
	line_printable(pattern, pat, sizeof(pat));
	line_printable(cmd, sent, sizeof(sent));
	return asph_error_set(err, -EPROTO, "unexpected reply '%s' to '%s' (expected %s): a "
			      "garbled line or the answer to another command", shown, sent, pat);
}

/* A reply that matched nothing expected: the device's error, else a
 * reply out of place. */
static int refuse_reply(struct asph_device *d, const char *cmd, const char *reply,
			const char *pattern, uint64_t deadline, struct asph_error *err)
{
	int r = error_reply(d, reply, deadline, err);

	return r < 0 ? r : unexpected(cmd, reply, pattern, err);
}

int line_query(struct asph_device *d, const char *cmd, const char *pattern, const char *range,
	       struct line_match *m, bool *oor, uint64_t deadline, struct asph_error *err)
{
	const char *what = cmd ? cmd : "(a reading: the gauge's data button or foot switch; the "
				       "read_timeout option gives the operator longer)";
	char reply[LINE_REPLY_MAX];
	int r = cmd ? send_line(d, cmd, deadline, err) : 0;

	if (r == 0)
		r = read_reply(d, what, reply, sizeof(reply), deadline,
			       cmd ? d->reply_ms : transport_ms_left(deadline), err);
	if (r < 0)
		return r;
	if (line_match(pattern, reply, &d->vars, m))
		return 0;
	if (range && *range && line_match(range, reply, &d->vars, m)) {
		*oor = true;
		return 0;
	}
	return refuse_reply(d, cmd ? cmd : "(a reading)", reply, pattern, deadline, err);
}

/* The error query: 0 when the device reports none, else its error. */
static int run_error_query(struct asph_device *d, uint64_t deadline, struct asph_error *err)
{
	struct line_match m;
	char cmd[LINE_REPLY_MAX / 2];
	bool oor = false;

	memset(&m, 0, sizeof(m));
	int r = line_expand(d->prof.error_query, &d->vars, cmd, sizeof(cmd), err);
	if (r == 0)
		r = line_query(d, cmd, d->prof.error_reply_pattern, NULL, &m, &oor, deadline, err);
	if (r < 0)
		return r;
	if (m.has_code ? m.code == d->prof.error_none : !strcmp(m.text, d->prof.error_none_text))
		return 0;
	return device_error(d, m.code, m.has_code, m.has_text ? m.text : "", err);
}

/* A pause of ms within the deadline; stop() ends the operation after it. */
static int nap(struct asph_device *d, unsigned ms, uint64_t deadline, struct asph_error *err)
{
	unsigned left = transport_ms_left(deadline);

	msleep(ms < left ? ms : left);
	return atomic_load(&d->stop) && !d->stopping ? asph_error_set(err, -ECANCELED, "stopped") : 0;
}

/* Repeats the query until its done pattern matches (and its mask), while
 * the replies match a busy pattern. */
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
		if (!busy)
			return refuse_reply(d, cmd, reply, st->reply, deadline, err);
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

/* A command and the acknowledgement the profile expects of it, if any. */
static int send_step(struct asph_device *d, const struct line_step *st, const char *cmd,
		     struct line_match *m, uint64_t deadline, struct asph_error *err)
{
	const char *ack = st->ack[0] ? st->ack : d->prof.ack;
	char reply[LINE_REPLY_MAX];
	int r = send_line(d, cmd, deadline, err);

	if (r == 0 && *ack) {
		r = read_reply(d, cmd, reply, sizeof(reply), deadline, d->reply_ms, err);
		if (r == 0 && !line_match(ack, reply, &d->vars, m))
			r = refuse_reply(d, cmd, reply, ack, deadline, err);
	}
	if (r == 0 && st->check)
		r = run_error_query(d, deadline, err);
	return r;
}

static int run_step(struct asph_device *d, const struct line_step *st, struct line_match *m,
		    bool *oor, uint64_t deadline, unsigned timeout_ms, struct asph_error *err)
{
	char cmd[LINE_REPLY_MAX / 2];
	int r = 0;

	if (st->kind == LINE_STEP_SEND || st->kind == LINE_STEP_QUERY || st->kind == LINE_STEP_WAIT)
		r = line_expand(st->command, &d->vars, cmd, sizeof(cmd), err);
	if (r < 0)
		return r;
	switch (st->kind) {
	case LINE_STEP_SEND:
		return send_step(d, st, cmd, m, deadline, err);
	case LINE_STEP_QUERY:
		return line_query(d, cmd, st->reply, st->range, m, oor, deadline, err);
	case LINE_STEP_READ:
		return line_query(d, NULL, st->reply, st->range, m, oor, deadline, err);
	case LINE_STEP_WAIT:
		return wait_step(d, st, cmd, m, deadline, timeout_ms, err);
	case LINE_STEP_CHECK:
		return run_error_query(d, deadline, err);
	case LINE_STEP_DELAY:
		return nap(d, st->ms, deadline, err);
	case LINE_STEP_DTR:
		return line_link_dtr_pulse(d->t, st->ms, err);
	}
	return asph_error_set(err, -EINVAL, "unknown step");
}

/* Says which operation (and axis) an error happened in. */
static int locate(const struct asph_device *d, enum line_op_id id, const struct line_step *st,
		  int k, int r, struct asph_error *err)
{
	if (!err)
		return r;
	if (st->per_axis && r != -ECANCELED)
		return asph_error_set_at(err, r, NULL, 0, 0, NULL, "axis %s (%s): %s: %s",
					 d->info.axes[k].name[0] ? d->info.axes[k].name : "?",
					 d->ids[k], line_op_name(id), err->message);
	return asph_error_set_at(err, r, NULL, 0, 0, NULL, "%s: %s", line_op_name(id),
				 err->message);
}

int line_run_op(struct asph_device *d, enum line_op_id id, unsigned mask, struct line_match *m,
		bool *oor, uint64_t deadline, unsigned timeout_ms, struct asph_error *err)
{
	const struct line_op *op = &d->prof.ops[id];

	if (atomic_load(&d->stop) && !d->stopping)
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
			if (r < 0)
				return locate(d, id, st, k, r, err);
			if (!st->per_axis)
				break;
		}
	}
	return 0;
}

/* ------------------------------------------------------------ stopping */

/* The stop operation's commands, written straight to the link: after
 * stop() has cancelled the transport, or on a link made to stop a stage.
 * No reply is waited for. */
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
				int n = snprintf(line, sizeof(line), "%s%s", cmd,
						 single_control_byte(cmd) ? "" : d->prof.send_terminator);
				if (n > 0 && (size_t)n < sizeof(line))
					line_link_send_raw(d->t, line, (size_t)n, 200);
			}
			if (!st->per_axis)
				break;
		}
	}
	pthread_mutex_unlock(&d->lock);
}

/* A link made again only to stop the stage: a stop() meanwhile must not
 * cancel it. 0 when the stop went out. */
static int relink_and_stop(struct asph_device *d, struct asph_error *err)
{
	pthread_mutex_lock(&d->lock);
	d->stopping = true;
	pthread_mutex_unlock(&d->lock);
	int r = relink(d, err);
	if (r == 0)
		send_stop(d);
	pthread_mutex_lock(&d->lock);
	d->stopping = false;
	/* the stop() that came meanwhile holds for what follows */
	if (d->t && atomic_load(&d->stop))
		transport_cancel(d->t);
	pthread_mutex_unlock(&d->lock);
	return r;
}

int line_dev_finish(struct asph_device *d, int r, struct asph_error *err)
{
	struct asph_error e;
	char name[300];

	if (r >= 0 || !d->stage)
		return r;
	if (r != -ENODEV) {
		send_stop(d);
		return r;
	}
	asph_error_clear(&e);
	line_dev_name(d, name, sizeof(name));
	if (relink_and_stop(d, &e) == 0) {
		if (err)
			asph_error_set_at(err, r, NULL, 0, 0, NULL, "%s; %s again and stopped the stage",
					  err->message, d->lp.serial ? "opened the port" : "connected");
	} else if (err) {
		asph_error_set_at(err, r, NULL, 0, 0, NULL, "%s; could not %s %s again to stop the "
				  "stage (%s): the controller's own limits and watchdog are what "
				  "protect the machine now", err->message,
				  d->lp.serial ? "open" : "connect to", name, e.message);
	}
	return r;
}
