/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Simulated line-protocol devices (see line-sim.h). */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>
#include <ctype.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include "line-sim.h"

struct sim_axis {
	double from, to, t0, dur;       /* a move: from, to (mm) over dur s from t0 */
	bool servo, referenced;
	double vel;
};

struct linesim {
	struct linesim_config c;
	pthread_t th;
	pthread_mutex_t lock;
	int listen_fd, conn_fd, master_fd, wake[2];
	char slave[64];
	double t_start;
	struct sim_axis ax[3];
	const char *ids[3];
	long error;                     /* the error the device keeps (PI, Newport) */
	bool enabled, linked, echo, verbose; /* LinuxCNC: the session */
	char text[160];                 /* LinuxCNC: the last error's text */
	bool stalled, garble_next, partial_next;
	double replug_at;               /* real time a dropped serial line comes back, 0: not */
	enum linesim_fault fault;
	int fault_at;                   /* moves or readings from now */
	struct linesim_stats st;
	char in[4096];
	size_t in_len;
	char out[8192];
	size_t out_len;
};

/* ------------------------------------------------------------- time */

static double real_now(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* Simulated seconds since the start. */
static double sim_now(const struct linesim *s)
{
	return (real_now() - s->t_start) / s->c.time_scale;
}

static double axis_pos(const struct linesim *s, int k)
{
	const struct sim_axis *a = &s->ax[k];
	double t = sim_now(s) - a->t0;

	if (a->dur <= 0 || t >= a->dur)
		return a->to;
	return a->from + (a->to - a->from) * (t < 0 ? 0 : t / a->dur);
}

static bool axis_moving(const struct linesim *s, int k)
{
	return s->ax[k].dur > 0 && sim_now(s) - s->ax[k].t0 < s->ax[k].dur;
}

static bool any_moving(const struct linesim *s)
{
	return axis_moving(s, 0) || axis_moving(s, 1) || axis_moving(s, 2);
}

static void start_move(struct linesim *s, int k, double to)
{
	struct sim_axis *a = &s->ax[k];
	double from = axis_pos(s, k), v = a->vel > 0 ? a->vel : s->c.speed;

	a->from = from;
	a->to = to;
	a->t0 = sim_now(s);
	a->dur = fabs(to - from) / v;
}

static void stop_axis(struct linesim *s, int k)
{
	struct sim_axis *a = &s->ax[k];
	double p = axis_pos(s, k);

	a->from = a->to = p;
	a->dur = 0;
}

/* ----------------------------------------------------------- replies */

static void reply_raw(struct linesim *s, const char *b, size_t n)
{
	if (s->stalled || s->out_len + n > sizeof(s->out))
		return;
	memcpy(s->out + s->out_len, b, n);
	s->out_len += n;
}

/* A reply line with its terminator; a fault may garble or cut it. */
__attribute__((format(printf, 3, 4)))
static void reply(struct linesim *s, const char *term, const char *fmt, ...)
{
	char buf[1024];
	va_list ap;

	va_start(ap, fmt);
	int n = vsnprintf(buf, sizeof(buf), fmt, ap);
	va_end(ap);
	if (n < 0)
		return;
	if (s->garble_next) {
		/* line noise of a bad cable: control bytes inside the text */
		s->garble_next = false;
		reply_raw(s, "\x13\x02#\x7f", 4);
		reply_raw(s, buf, (size_t)n / 2);
		reply_raw(s, term, strlen(term));
		return;
	}
	reply_raw(s, buf, (size_t)n);
	if (s->partial_next) {
		s->partial_next = false;
		s->stalled = true;      /* and then nothing more */
		return;
	}
	reply_raw(s, term, strlen(term));
}

/* A move or reading counts towards an injected fault; true when this is
 * the one. */
static bool fault_now(struct linesim *s, enum linesim_fault *f)
{
	*f = LINESIM_NONE;
	if (!s->fault || --s->fault_at > 0)
		return false;
	*f = s->fault;
	s->fault = LINESIM_NONE;
	switch (*f) {
	case LINESIM_GARBLE: s->garble_next = true; break;
	case LINESIM_STALL: s->stalled = true; break;
	case LINESIM_PARTIAL: s->partial_next = true; break;
	default: break;
	}
	return true;
}

static int axis_index(const struct linesim *s, const char *id)
{
	for (int k = 0; k < 3; k++)
		if (!strcasecmp(id, s->ids[k]))
			return k;
	return -1;
}

/* Drops the connection in the middle of things (TCP: the next one is
 * accepted; a pty: the line is gone). */
static void disconnect(struct linesim *s)
{
	if (s->c.serial) {
		if (s->master_fd >= 0)
			close(s->master_fd);
		s->master_fd = -1;
		/* the adapter's by-id name goes with it, as udev removes it:
		 * the pty's number is free for any other */
		if (s->c.link)
			unlink(s->c.link);
		if (s->c.link && s->c.replug)
			s->replug_at = real_now() + s->c.replug_s;
	} else if (s->conn_fd >= 0) {
		close(s->conn_fd);
		s->conn_fd = -1;
	}
	s->in_len = 0;
	s->out_len = 0;
}

/* ------------------------------------------------- PI GCS 2.0 */

static int words(char *line, char **w, int max)
{
	int n = 0;
	for (char *save, *t = strtok_r(line, " ", &save); t && n < max; t = strtok_r(NULL, " ", &save))
		w[n++] = t;
	return n;
}

/* One answer line per axis, continued lines ending in " \n". */
static void pi_axes_answer(struct linesim *s, char **w, int n, int kind)
{
	int idx[3], m = 0;

	for (int i = 1; i < n; i++) {
		int k = axis_index(s, w[i]);
		if (k < 0) {
			s->error = 15;
			return;
		}
		if (m < 3)
			idx[m++] = k;
	}
	if (n == 1)
		for (m = 0; m < 3; m++)
			idx[m] = m;
	for (int i = 0; i < m; i++) {
		int k = idx[i];
		const char *end = i + 1 < m ? " " : "";
		if (kind == 0)
			reply(s, "\n", "%s=%.7f%s", s->ids[k], axis_pos(s, k), end);
		else if (kind == 1)
			reply(s, "\n", "%s=%d%s", s->ids[k], !axis_moving(s, k), end);
		else
			reply(s, "\n", "%s=%d%s", s->ids[k], s->ax[k].referenced && !axis_moving(s, k), end);
	}
}

static void pi_mov(struct linesim *s, char **w, int n)
{
	enum linesim_fault f;
	double to[3];
	int ks[3], m = 0;

	if (n < 3 || (n - 1) % 2) {
		s->error = 24;
		return;
	}
	s->st.moves++;
	for (int i = 1; i + 1 < n && m < 3; i += 2) {
		int k = axis_index(s, w[i]);
		char *end;
		if (k < 0) {
			s->error = 15;
			return;
		}
		to[m] = strtod(w[i + 1], &end);
		if (*end || !isfinite(to[m])) {
			s->error = 25;
			return;
		}
		if (!s->ax[k].referenced || !s->ax[k].servo) {
			s->error = 5;
			return;
		}
		if (fabs(to[m]) > s->c.travel) {
			s->error = 7;
			return;
		}
		ks[m++] = k;
	}
	if (fault_now(s, &f) && f == LINESIM_DEVICE_ERROR) {
		/* as if the stage's soft limits were narrower than configured */
		s->error = 7;
		return;
	}
	for (int i = 0; i < m; i++)
		start_move(s, ks[i], to[i]);
	if (f == LINESIM_DISCONNECT)
		disconnect(s);
}

static void pi_line(struct linesim *s, char *line)
{
	char *w[16];
	int n = words(line, w, 16);

	if (n == 0)
		return;
	if (!strcmp(w[0], "ERR?")) {
		reply(s, "\n", "%ld", s->error);
		s->error = 0;
	} else if (!strcmp(w[0], "POS?")) {
		pi_axes_answer(s, w, n, 0);
	} else if (!strcmp(w[0], "ONT?")) {
		pi_axes_answer(s, w, n, 1);
	} else if (!strcmp(w[0], "FRF?")) {
		pi_axes_answer(s, w, n, 2);
	} else if (!strcmp(w[0], "MOV")) {
		pi_mov(s, w, n);
	} else if (!strcmp(w[0], "SVO") || !strcmp(w[0], "VEL") || !strcmp(w[0], "FRF")) {
		if (w[0][0] != 'F' && (n < 3 || (n - 1) % 2)) {
			s->error = 24;
			return;
		}
		for (int i = 1; i < n; i += w[0][0] == 'F' ? 1 : 2) {
			int k = axis_index(s, w[i]);
			if (k < 0) {
				s->error = 15;
				return;
			}
			if (w[0][0] == 'S')
				s->ax[k].servo = atoi(w[i + 1]) != 0;
			else if (w[0][0] == 'V')
				s->ax[k].vel = strtod(w[i + 1], NULL);
			else if (!s->ax[k].servo)
				s->error = 5;
			else {
				/* reference move: to the reference switch at 0 */
				s->ax[k].referenced = true;
				start_move(s, k, 0);
			}
		}
	} else if (!strcmp(w[0], "STP") || !strcmp(w[0], "HLT")) {
		for (int k = 0; k < 3; k++)
			stop_axis(s, k);
		s->st.stops++;
		s->error = 10;
	} else {
		s->error = 2;
	}
}

/* Single-character commands, answered at once. */
static bool pi_char(struct linesim *s, char c)
{
	unsigned mask = 0;

	switch (c) {
	case 0x05:
		for (int k = 0; k < 3; k++)
			mask |= (unsigned)axis_moving(s, k) << k;
		reply(s, "\n", "%X", mask);
		return true;
	case 0x07:
		reply(s, "\n", "%c", any_moving(s) ? '\xb0' : '\xb1');
		return true;
	case 0x18:
		for (int k = 0; k < 3; k++)
			stop_axis(s, k);
		s->st.stops++;
		s->error = 10;
		return true;
	}
	return false;
}

/* ---------------------------------------------- Newport ESP301 */

/* "1PA12.5": the axis, two letters, a parameter; "TE?" without axis. */
static void newport_line(struct linesim *s, char *line)
{
	enum linesim_fault f;
	char *end;

	if (!strcmp(line, "TE?")) {
		reply(s, "\r\n", "%ld", s->error);
		s->error = 0;
		return;
	}
	long ax = strtol(line, &end, 10);
	if (end == line) {
		s->error = 37;
		return;
	}
	int k = (int)ax - 1;
	if (k < 0 || k > 2) {
		s->error = 9;
		return;
	}
	const char *cmd = end, *arg = end + 2;
	if (strlen(cmd) < 2) {
		s->error = 6;
		return;
	}
	if (!strncmp(cmd, "MO", 2)) {
		s->ax[k].servo = true;
	} else if (!strncmp(cmd, "VA", 2)) {
		s->ax[k].vel = strtod(arg, NULL);
	} else if (!strcmp(cmd, "OR")) {
		if (!s->ax[k].servo) {
			s->error = 13;
			return;
		}
		s->ax[k].referenced = true;
		start_move(s, k, 0);
	} else if (!strcmp(cmd, "MD?")) {
		reply(s, "\r\n", "%d", !axis_moving(s, k));
	} else if (!strcmp(cmd, "TP")) {
		reply(s, "\r\n", "%.6f", axis_pos(s, k));
	} else if (!strcmp(cmd, "ST")) {
		stop_axis(s, k);
		s->st.stops++;
	} else if (!strncmp(cmd, "PA", 2)) {
		double to = strtod(arg, &end);
		if (!*arg || *end) {
			s->error = 38;
			return;
		}
		if (!s->ax[k].servo) {
			s->error = 13;
			return;
		}
		s->st.moves++;
		bool fault = fault_now(s, &f) && f == LINESIM_DEVICE_ERROR;
		if (fabs(to) > s->c.travel || fault) {
			s->error = (long)(k + 1) * 100 + (to < 0 && !fault ? 7 : 6);
			return;
		}
		start_move(s, k, to);
		if (f == LINESIM_DISCONNECT)
			disconnect(s);
	} else {
		s->error = 6;
	}
}

/* ------------------------------------------- Aerotech Ensemble */

#define AXISFAULT_CW_SOFTWARE_LIMIT 16

static void aerotech_line(struct linesim *s, char *line)
{
	enum linesim_fault f;
	char *w[8], arg[64] = "";
	int n = words(line, w, 8), k = -1;

	if (n == 0)
		return;
	/* FUNCTION(AXIS) queries */
	char *open = strchr(w[0], '('), *close = open ? strchr(open, ')') : NULL;
	if (open && close && !close[1]) {
		*open = '\0';
		*close = '\0';
		snprintf(arg, sizeof(arg), "%s", open + 1);
		k = axis_index(s, arg);
		if (k < 0) {
			reply(s, "\n", "!");
			return;
		}
		if (!strcmp(w[0], "PFBKPROG"))
			reply(s, "\n", "%%%.6f", axis_pos(s, k));
		else if (!strcmp(w[0], "AXISSTATUS"))
			reply(s, "\n", "%%%d", (int)s->ax[k].servo | (int)s->ax[k].referenced << 1 |
			      (int)!axis_moving(s, k) << 2 | (int)axis_moving(s, k) << 3);
		else if (!strcmp(w[0], "AXISFAULT"))
			reply(s, "\n", "%%%ld", s->error);
		else
			reply(s, "\n", "!");
		return;
	}
	if (n == 3 && !strcmp(w[0], "WAIT") && !strcmp(w[1], "MODE") && !strcmp(w[2], "NOWAIT")) {
		reply(s, "\n", "%%");
		return;
	}
	if (n == 1 && !strcmp(w[0], "ACKNOWLEDGEALL")) {
		s->error = 0;
		reply(s, "\n", "%%");
		return;
	}
	if (n < 2 || (k = axis_index(s, w[1])) < 0) {
		reply(s, "\n", "!");
		return;
	}
	if (!strcmp(w[0], "ENABLE") && n == 2) {
		s->ax[k].servo = true;
	} else if (!strcmp(w[0], "HOME") && n == 2) {
		if (!s->ax[k].servo || s->error) {
			reply(s, "\n", "#");
			return;
		}
		s->ax[k].referenced = true;
		start_move(s, k, 0);
	} else if (!strcmp(w[0], "ABORT") && n == 2) {
		stop_axis(s, k);
		s->st.stops++;
	} else if (!strcmp(w[0], "MOVEABS") && n == 3) {
		char *end;
		double to = strtod(w[2], &end);
		if (*end) {
			reply(s, "\n", "!");
			return;
		}
		s->st.moves++;
		bool fault = fault_now(s, &f) && f == LINESIM_DEVICE_ERROR;
		if (!s->ax[k].referenced || !s->ax[k].servo || s->error || fault ||
		    fabs(to) > s->c.travel) {
			if (fault || fabs(to) > s->c.travel)
				s->error = AXISFAULT_CW_SOFTWARE_LIMIT;
			reply(s, "\n", "#");
			return;
		}
		start_move(s, k, to);
		if (f == LINESIM_DISCONNECT) {
			disconnect(s);
			return;
		}
	} else {
		reply(s, "\n", "!");
		return;
	}
	reply(s, "\n", "%%");
}

/* ----------------------------------------------- linuxcncrsh */

static void lcnc_set(struct linesim *s, char **w, int n, bool verbose)
{
	enum linesim_fault f;
	bool ok = true;

	if (!s->enabled && strcasecmp(w[1], "enable") && strcasecmp(w[1], "echo") &&
	    strcasecmp(w[1], "verbose")) {
		ok = false;
	} else if (!strcasecmp(w[1], "enable")) {
		s->enabled = n == 3 && !strcmp(w[2], "EMCTOO");
		ok = s->enabled;
	} else if (!strcasecmp(w[1], "joint_home")) {
		for (int k = 0; k < 3; k++) {
			s->ax[k].referenced = true;
			start_move(s, k, 0);
		}
	} else if (!strcasecmp(w[1], "abort")) {
		for (int k = 0; k < 3; k++)
			stop_axis(s, k);
		s->st.stops++;
	} else if (!strcasecmp(w[1], "mdi")) {
		double to[3];
		bool seen[3] = { false, false, false };
		for (int i = 2; i < n; i++) {
			if (!strcasecmp(w[i], "G53") || !strcasecmp(w[i], "G0"))
				continue;
			int k = -1;
			for (int a = 0; a < 3; a++)
				if (toupper((unsigned char)w[i][0]) == "XYZ"[a])
					k = a;
			if (k < 0) {
				/* rs274ngc's check_other_codes (interp_check.cc): a Q
				 * word needs a code that uses it; a letter the
				 * interpreter does not know is a bad character */
				ok = false;
				if (toupper((unsigned char)w[i][0]) == 'Q')
					snprintf(s->text, sizeof(s->text), "Q word with no G5, G10, G64, "
						 "G73, G71, G76, G83, M19, M66, M67, M68 or user M code "
						 "that uses it");
				else
					snprintf(s->text, sizeof(s->text), "Bad character '%c' used",
						 tolower((unsigned char)w[i][0]));
				break;
			}
			to[k] = strtod(w[i] + 1, NULL);
			seen[k] = true;
		}
		if (ok) {
			s->st.moves++;
			bool fault = fault_now(s, &f) && f == LINESIM_DEVICE_ERROR;
			for (int k = 0; k < 3 && ok; k++)
				if (seen[k] && (fault || fabs(to[k]) > s->c.travel)) {
					ok = false;
					snprintf(s->text, sizeof(s->text),
						 "Move on line 0 would exceed joint %d's positive limit", k);
				}
			for (int k = 0; k < 3 && ok; k++)
				if (seen[k])
					start_move(s, k, to[k]);
			if (f == LINESIM_DISCONNECT) {
				disconnect(s);
				return;
			}
		}
	}
	if (verbose || !ok) {
		char up[32];
		snprintf(up, sizeof(up), "%s", w[1]);
		for (char *c = up; *c; c++)
			*c = (char)toupper((unsigned char)*c);
		reply(s, "\r\n", "SET %s %s", up, ok ? "ACK" : "NAK");
	}
}

static void linuxcnc_line(struct linesim *s, char *line)
{
	char copy[512], *w[16];

	if (s->echo)
		reply(s, "\r\n", "%s", line);
	snprintf(copy, sizeof(copy), "%s", line);
	int n = words(copy, w, 16);
	if (n == 0)
		return;
	if (!strcasecmp(w[0], "hello")) {
		s->linked = n >= 3 && !strcmp(w[1], "EMC");
		reply(s, "\r\n", s->linked ? "HELLO ACK EMCNETSVR 1.1" : "HELLO NAK");
		return;
	}
	if (!s->linked || n < 2)
		return;
	if (!strcasecmp(w[0], "set") && !strcasecmp(w[1], "echo") && n == 3) {
		s->echo = !strcasecmp(w[2], "on");
		return;
	}
	if (!strcasecmp(w[0], "set") && !strcasecmp(w[1], "verbose") && n == 3) {
		s->verbose = !strcasecmp(w[2], "on");
		if (s->verbose)
			reply(s, "\r\n", "SET VERBOSE ACK");
		return;
	}
	if (!strcasecmp(w[0], "set")) {
		lcnc_set(s, w, n, s->verbose);
		return;
	}
	if (strcasecmp(w[0], "get"))
		return;
	if (!strcasecmp(w[1], "abs_act_pos"))
		reply(s, "\r\n", "ABS_ACT_POS %f %f %f %f %f %f", axis_pos(s, 0), axis_pos(s, 1),
		      axis_pos(s, 2), 0.0, 0.0, 0.0);
	else if (!strcasecmp(w[1], "program_status"))
		reply(s, "\r\n", "PROGRAM_STATUS %s", any_moving(s) ? "RUNNING" : "IDLE");
	else if (!strcasecmp(w[1], "joint_homed"))
		reply(s, "\r\n", "JOINT_HOMED %s %s %s",
		      s->ax[0].referenced && !any_moving(s) ? "YES" : "NO",
		      s->ax[1].referenced && !any_moving(s) ? "YES" : "NO",
		      s->ax[2].referenced && !any_moving(s) ? "YES" : "NO");
	else if (!strcasecmp(w[1], "error")) {
		reply(s, "\r\n", "ERROR %s", s->text[0] ? s->text : "OK");
		s->text[0] = '\0';
	}
}

/* ------------------------------------------------------- sensors */

/*
 * A reading for a request: false when the request gets no reading reply,
 * because the line dropped or the injected device error was answered
 * (with error, which a device without one leaves NULL); *ok false when
 * there is no target.
 */
static bool sense(struct linesim *s, const char *error, double *mm, bool *ok)
{
	enum linesim_fault f;

	s->st.readings++;
	fault_now(s, &f);
	if (f == LINESIM_DISCONNECT) {
		disconnect(s);
		return false;
	}
	if (f == LINESIM_DEVICE_ERROR) {
		if (error)
			reply(s, "\r", "%s", error);
		return false;
	}
	*ok = s->c.sense(s->c.sense_data, mm);
	return true;
}

/* Keyence LK-G: "M1" answers "M1,+0.12345": a sign and seven characters
 * with the point where the settings put it; out of range "+FFFFFF". */
static void keyence_line(struct linesim *s, char *line)
{
	double mm;

	if (line[0] != 'M' && line[0] != 'm') {
		reply(s, "\r", "ER,%.2s,00", line);
		return;
	}
	if (strlen(line) != 2 || (line[1] != '1' && line[1] != '2')) {
		reply(s, "\r", "ER,%.2s,%s", line, strlen(line) == 2 ? "22" : "20");
		return;
	}
	if (line[1] == '2') {           /* no second head on this controller */
		reply(s, "\r", "ER,M2,01");
		return;
	}
	bool ok;
	if (!sense(s, "ER,M1,99", &mm, &ok))
		return;
	if (!ok || fabs(mm) >= 9.99999)
		reply(s, "\r", "M1,%cFFFFFF", ok && mm < 0 ? '-' : '+');
	else
		reply(s, "\r", "M1,%c%07.5f", mm < 0 ? '-' : '+', fabs(mm));
}

/* Mitutoyo USB-ITN (virtual COM): a request "1" answers "01A+0000.123":
 * the code, the channel, A, the sign and eight characters with a
 * floating point. */
static void mitutoyo_line(struct linesim *s, char *line)
{
	double mm;

	if (strcmp(line, "1")) {
		/* the cable knows one request; anything else is not answered */
		return;
	}
	bool ok;
	/* the specification names no error reply: a gauge that has nothing
	 * to send sends nothing */
	if (!sense(s, NULL, &mm, &ok) || !ok)
		return;
	reply(s, "\r", "01A%c%08.5f", mm < 0 ? '-' : '+', fabs(mm));
}

/* Sylvac: "?" (or "PRI") answers the displayed value, sign, integer part,
 * point, decimals; errors are "ERR" and a number. */
static void sylvac_line(struct linesim *s, char *line)
{
	double mm;

	if (strcasecmp(line, "?") && strcasecmp(line, "PRI")) {
		reply(s, "\r", "ERR1");
		return;
	}
	bool ok;
	if (!sense(s, "ERR0", &mm, &ok))
		return;
	if (!ok)
		reply(s, "\r", "ERR3");
	else
		reply(s, "\r", "%c%.5f", mm < 0 ? '-' : '+', fabs(mm));
}

/* ------------------------------------------------------------ serving */

static void handle_line(struct linesim *s, char *line)
{
	s->st.commands++;
	switch (s->c.kind) {
	case LINESIM_PI: pi_line(s, line); break;
	case LINESIM_NEWPORT: newport_line(s, line); break;
	case LINESIM_AEROTECH: aerotech_line(s, line); break;
	case LINESIM_LINUXCNC: linuxcnc_line(s, line); break;
	case LINESIM_KEYENCE: keyence_line(s, line); break;
	case LINESIM_MITUTOYO: mitutoyo_line(s, line); break;
	case LINESIM_SYLVAC: sylvac_line(s, line); break;
	default: break;
	}
}

static const char *terminators(enum linesim_kind k)
{
	switch (k) {
	case LINESIM_PI: case LINESIM_AEROTECH: return "\n";
	case LINESIM_LINUXCNC: return "\r\n";
	default: return "\r";
	}
}

static void process(struct linesim *s)
{
	const char *terms = terminators(s->c.kind);
	size_t start = 0;

	for (size_t i = 0; i < s->in_len; i++) {
		char c = s->in[i];
		if (s->c.kind == LINESIM_PI && i == start && pi_char(s, c)) {
			s->st.commands++;
			start = i + 1;
			continue;
		}
		if (!strchr(terms, c))
			continue;
		s->in[i] = '\0';
		if (i > start)
			handle_line(s, s->in + start);
		start = i + 1;
		if (s->in_len == 0)
			return;         /* disconnected */
	}
	memmove(s->in, s->in + start, s->in_len - start);
	s->in_len -= start;
}

static int device_fd(const struct linesim *s)
{
	return s->c.serial ? s->master_fd : s->conn_fd;
}

static void flush_out(struct linesim *s)
{
	int fd = device_fd(s);
	size_t o = 0;

	while (fd >= 0 && o < s->out_len) {
		ssize_t n = write(fd, s->out + o, s->out_len - o);
		if (n <= 0)
			break;
		o += (size_t)n;
	}
	s->out_len = 0;
}

/* A new pty pair; with a link, the link (re)pointed at its slave in one
 * step, as udev moves a by-id name to a re-enumerated adapter. */
static int open_pty(struct linesim *s)
{
	char tmp[600];

	s->master_fd = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
	if (s->master_fd < 0 || grantpt(s->master_fd) < 0 || unlockpt(s->master_fd) < 0 ||
	    ptsname_r(s->master_fd, s->slave, sizeof(s->slave)) != 0)
		return -errno;
	if (!s->c.link)
		return 0;
	snprintf(tmp, sizeof(tmp), "%s.new", s->c.link);
	unlink(tmp);
	if (symlink(s->slave, tmp) < 0 || rename(tmp, s->c.link) < 0)
		return -errno;
	return 0;
}

/* A dropped serial line whose time to come back has come. */
static void replug_due(struct linesim *s)
{
	if (s->replug_at <= 0 || real_now() < s->replug_at)
		return;
	s->replug_at = 0;
	s->in_len = s->out_len = 0;
	s->stalled = false;
	if (open_pty(s) == 0)
		s->st.connections++;
}

static void *serve(void *data)
{
	struct linesim *s = data;

	for (;;) {
		struct pollfd p[2] = { { s->wake[0], POLLIN, 0 }, { -1, POLLIN, 0 } };
		pthread_mutex_lock(&s->lock);
		replug_due(s);
		p[1].fd = device_fd(s) >= 0 ? device_fd(s) : (s->c.serial ? -1 : s->listen_fd);
		int wait_ms = s->replug_at > 0 ? 5 : 100;
		pthread_mutex_unlock(&s->lock);
		if (poll(p, 2, wait_ms) < 0 && errno != EINTR)
			break;
		if (p[0].revents)
			break;
		if (!p[1].revents)
			continue;
		pthread_mutex_lock(&s->lock);
		if (!s->c.serial && s->conn_fd < 0) {
			s->conn_fd = accept4(s->listen_fd, NULL, NULL, SOCK_CLOEXEC);
			if (s->conn_fd >= 0) {
				s->st.connections++;
				s->stalled = false;
				/* linuxcncrsh: a new session, echo on */
				s->linked = s->enabled = s->verbose = false;
				s->echo = true;
			}
		} else {
			ssize_t n = read(device_fd(s), s->in + s->in_len, sizeof(s->in) - s->in_len);
			if (n <= 0) {
				if (!s->c.serial)
					disconnect(s);
			} else {
				s->in_len += (size_t)n;
				process(s);
				flush_out(s);
				if (s->in_len == sizeof(s->in))
					s->in_len = 0;
			}
		}
		pthread_mutex_unlock(&s->lock);
	}
	return NULL;
}

static int open_endpoint(struct linesim *s, char *address, size_t size)
{
	if (s->c.serial) {
		int r = open_pty(s);
		if (r < 0)
			return r;
		snprintf(address, size, "%s", s->c.link ? s->c.link : s->slave);
		return 0;
	}
	struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
	socklen_t l = sizeof(a);
	s->listen_fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
	if (s->listen_fd < 0 || bind(s->listen_fd, (struct sockaddr *)&a, sizeof(a)) < 0 ||
	    listen(s->listen_fd, 4) < 0 || getsockname(s->listen_fd, (struct sockaddr *)&a, &l) < 0)
		return -errno;
	snprintf(address, size, "%d", ntohs(a.sin_port));
	return 0;
}

int linesim_start(const struct linesim_config *c, struct linesim **out, char *address,
		  size_t size)
{
	static const char *const pi_ids[3] = { "1", "2", "3" };
	static const char *const xyz[3] = { "X", "Y", "Z" };
	struct linesim *s = calloc(1, sizeof(*s));

	if (!s)
		return -ENOMEM;
	s->c = *c;
	if (s->c.time_scale <= 0)
		s->c.time_scale = 1e-3;
	if (s->c.speed <= 0)
		s->c.speed = 20;
	if (s->c.travel <= 0)
		s->c.travel = 50;
	s->listen_fd = s->conn_fd = s->master_fd = -1;
	s->echo = true;
	for (int k = 0; k < 3; k++)
		s->ids[k] = c->kind == LINESIM_PI || c->kind == LINESIM_NEWPORT ? pi_ids[k] : xyz[k];
	pthread_mutex_init(&s->lock, NULL);
	s->t_start = real_now();
	int r = pipe2(s->wake, O_CLOEXEC);
	if (r == 0)
		r = open_endpoint(s, address, size);
	if (r == 0 && pthread_create(&s->th, NULL, serve, s) != 0)
		r = -EAGAIN;
	if (r < 0) {
		if (s->listen_fd >= 0)
			close(s->listen_fd);
		if (s->master_fd >= 0)
			close(s->master_fd);
		free(s);
		return r;
	}
	*out = s;
	return 0;
}

void linesim_stop(struct linesim *s)
{
	if (!s)
		return;
	if (write(s->wake[1], "x", 1) == 1)
		pthread_join(s->th, NULL);
	s->c.replug = false;
	disconnect(s);
	if (s->listen_fd >= 0)
		close(s->listen_fd);
	close(s->wake[0]);
	close(s->wake[1]);
	pthread_mutex_destroy(&s->lock);
	free(s);
}

void linesim_inject(struct linesim *s, enum linesim_fault fault, int count)
{
	pthread_mutex_lock(&s->lock);
	s->fault = fault;
	s->fault_at = count;
	pthread_mutex_unlock(&s->lock);
}

void linesim_stats(struct linesim *s, struct linesim_stats *out)
{
	pthread_mutex_lock(&s->lock);
	*out = s->st;
	for (int k = 0; k < 3; k++)
		out->position[k] = axis_pos(s, k);
	out->moving = any_moving(s);
	out->homed = s->ax[0].referenced && s->ax[1].referenced && s->ax[2].referenced;
	pthread_mutex_unlock(&s->lock);
}

void linesim_operator(struct linesim *s)
{
	char request[] = "1";

	pthread_mutex_lock(&s->lock);
	/* the same line the request would bring */
	if (s->c.kind == LINESIM_MITUTOYO)
		mitutoyo_line(s, request);
	else if (s->c.kind == LINESIM_SYLVAC)
		sylvac_line(s, (char[]){ "PRI" });
	flush_out(s);
	pthread_mutex_unlock(&s->lock);
}

void linesim_position(struct linesim *s, double pos[3])
{
	pthread_mutex_lock(&s->lock);
	for (int k = 0; k < 3; k++)
		pos[k] = axis_pos(s, k);
	pthread_mutex_unlock(&s->lock);
}
