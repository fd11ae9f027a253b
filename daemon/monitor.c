/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>

#include "dirs.h"
#include "log.h"
#include "monitor.h"
#include "store.h"
#include "util-mem.h"
#include "util-time.h"

/* The checks of the health, in the order they are told (monitor.h). */
enum check {
	CHECK_INSTRUMENT_FAULT,
	CHECK_SINK_DOWN,
	CHECK_OUTBOX_BACKLOG,
	CHECK_OUTBOX_HELD,
	CHECK_DISK_LOW,
	CHECK_STORE_RESERVE,
	CHECK_QUEUE_STOPPED,
	N_CHECKS,
};

static const char *const check_names[N_CHECKS] = {
	[CHECK_INSTRUMENT_FAULT] = "instrument_fault",
	[CHECK_SINK_DOWN] = "sink_down",
	[CHECK_OUTBOX_BACKLOG] = "outbox_backlog",
	[CHECK_OUTBOX_HELD] = "outbox_held",
	[CHECK_DISK_LOW] = "disk_low",
	[CHECK_STORE_RESERVE] = "store_reserve",
	[CHECK_QUEUE_STOPPED] = "queue_stopped",
};

static const char *const error_names[MONITOR_N_ERRORS] = {
	[MONITOR_JOB_FAILED] = "job_failed",
	[MONITOR_MQTT_CONNECTION] = "mqtt_connection",
	[MONITOR_POSTGRES_CONNECTION] = "postgres_connection",
	[MONITOR_POSTGRES_REFUSED] = "postgres_refused",
};

struct sink {
	bool configured;
	bool up;
	int64_t down_since_ns;          /* realtime; while not up */
};

struct monitor {
	struct jobs *jobs;
	const struct instruments *instruments;
	const struct settings_limits *limits;
	const struct settings_health *health;
	char *state_dir;
	char *store_path;
	char *version;
	int state_fd;
	int64_t started_ns;
	struct outbox *outbox;
	struct sink sinks[OUTBOX_N_SINKS];
	uint64_t errors[MONITOR_N_ERRORS];
};

int monitor_new(const struct monitor_setup *setup, struct monitor **out)
{
	struct monitor *m = calloc(1, sizeof(*m));

	if (!m)
		return -ENOMEM;
	m->jobs = setup->jobs;
	m->instruments = setup->instruments;
	m->limits = setup->limits;
	m->health = setup->health;
	m->started_ns = setup->started_ns;
	m->state_dir = strdup(setup->state_dir);
	m->version = strdup(setup->version);
	m->state_fd = open(setup->state_dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	if (!m->state_dir || !m->version || m->state_fd < 0 ||
	    asprintf(&m->store_path, "%s/jobs.sqlite", setup->state_dir) < 0) {
		int r = m->state_fd < 0 && m->state_dir && m->version ? -errno : -ENOMEM;
		m->store_path = NULL;
		monitor_free(m);
		return r;
	}
	*out = m;
	return 0;
}

void monitor_free(struct monitor *m)
{
	if (!m)
		return;
	if (m->state_fd >= 0)
		close(m->state_fd);
	free(m->state_dir);
	free(m->store_path);
	free(m->version);
	free(m);
}

void monitor_set_outbox(struct monitor *m, struct outbox *o)
{
	m->outbox = o;
}

void monitor_add_sink(struct monitor *m, enum outbox_sink_kind k)
{
	m->sinks[k] = (struct sink){ .configured = true, .down_since_ns = now_realtime_ns() };
}

void monitor_sink_link(struct monitor *m, enum outbox_sink_kind k, bool up)
{
	struct sink *s = &m->sinks[k];

	if (!up && s->up)
		s->down_since_ns = now_realtime_ns();
	s->up = up;
}

void monitor_count_error(struct monitor *m, enum monitor_error kind)
{
	m->errors[kind]++;
}

void monitor_watch(const struct event *ev, void *data)
{
	struct monitor *m = data;
	const char *state;

	if (strcmp(ev->method, "job.state"))
		return;
	state = json_string_value(json_object_get(ev->params, "state"));
	if (state && !strcmp(state, "failed"))
		monitor_count_error(m, MONITOR_JOB_FAILED);
}

/* --------------------------------------------------------------- health */

static void __attribute__((format(printf, 3, 4)))
finding(json_t *list, enum check c, const char *fmt, ...)
{
	char detail[512];
	va_list ap;

	va_start(ap, fmt);
	vsnprintf(detail, sizeof(detail), fmt, ap);
	va_end(ap);
	json_array_append_new(list, json_pack("{s:s, s:s}", "check", check_names[c],
					      "detail", detail));
}

static void check_instruments(struct monitor *m, json_t *list)
{
	for (size_t i = 0; i < instruments_count(m->instruments); i++) {
		const struct instrument_activity *a = jobs_activity(m->jobs, i);
		if (!a->job && a->fault)
			finding(list, CHECK_INSTRUMENT_FAULT, "instrument %s: its last job stopped "
				"on a fault: %s", instruments_get(m->instruments, i)->name, a->fault);
	}
}

static void check_sinks(struct monitor *m, json_t *list, int64_t now)
{
	char since[ISO8601_SIZE];

	for (int k = 0; k < OUTBOX_N_SINKS; k++) {
		const struct sink *s = &m->sinks[k];
		const char *name = outbox_sink_name((enum outbox_sink_kind)k);
		int64_t oldest, held;

		if (!s->configured)
			continue;
		if (!s->up && now - s->down_since_ns > m->health->sink_down_s * NS_PER_SEC) {
			iso8601_utc(s->down_since_ns, 0, since, sizeof(since));
			finding(list, CHECK_SINK_DOWN, "%s: out of reach since %s (the messages wait "
				"in the outbox)", name, since);
		}
		if (!m->outbox)
			continue;
		oldest = outbox_oldest_ns(m->outbox, (enum outbox_sink_kind)k);
		if (oldest > 0 && now - oldest > m->health->outbox_age_s * NS_PER_SEC)
			finding(list, CHECK_OUTBOX_BACKLOG, "%s: %" PRId64 " message(s) wait, the "
				"oldest for %" PRId64 " s", name,
				outbox_waiting(m->outbox, (enum outbox_sink_kind)k),
				(int64_t)((now - oldest) / NS_PER_SEC));
		held = outbox_held(m->outbox, (enum outbox_sink_kind)k);
		if (held > 0)
			finding(list, CHECK_OUTBOX_HELD, "%s: %" PRId64 " message(s) refused for good "
				"wait for the next start (the log says why)", name, held);
	}
}

static void check_disk(struct monitor *m, json_t *list)
{
	uint64_t free_mb, keep = m->limits->min_free_disk_mb;

	if (keep && dirs_free_mb(m->state_fd, &free_mb) == 0 && free_mb < 2 * keep)
		finding(list, CHECK_DISK_LOW, "the state directory %s has %" PRIu64 " MiB free: "
			"below %" PRIu64 " MiB (limits.min_free_disk_mb) jobs are refused",
			m->state_dir, free_mb, keep);
	if (!store_reserve_ready(m->store_path))
		finding(list, CHECK_STORE_RESERVE, "%s.reserve is used up (the disk was full); "
			"it is made again when a job starts and there is room", m->store_path);
}

json_t *monitor_health(struct monitor *m)
{
	json_t *list = json_array();
	int64_t queued;

	if (!list || !m)
		return list;
	check_instruments(m, list);
	check_sinks(m, list, now_realtime_ns());
	check_disk(m, list);
	queued = jobs_counts(m->jobs)[JOB_QUEUED];
	if (!jobs_queue_running(m->jobs) && queued > 0)
		finding(list, CHECK_QUEUE_STOPPED, "the queue is stopped with %" PRId64 " job(s) "
			"waiting (asphctl queue start)", queued);
	return list;
}

/* -------------------------------------------------------------- metrics */

/* The text of one exposition: the format's escapes (HELP: backslash and
 * line feed; label values: those and the double quote). */
static void put_escaped(FILE *f, const char *s, bool quote)
{
	for (; *s; s++) {
		if (*s == '\\')
			fputs("\\\\", f);
		else if (*s == '\n')
			fputs("\\n", f);
		else if (quote && *s == '"')
			fputs("\\\"", f);
		else
			fputc(*s, f);
	}
}

static void family(FILE *f, const char *name, const char *type, const char *help)
{
	fprintf(f, "# HELP %s ", name);
	put_escaped(f, help, false);
	fprintf(f, "\n# TYPE %s %s\n", name, type);
}

/* A value as the format reads it (Go's ParseFloat): the shortest text
 * that reads back as v. */
static void put_value(FILE *f, double v)
{
	char text[32];

	if (isnan(v))
		fputs(" NaN\n", f);
	else if (isinf(v))
		fputs(v > 0 ? " +Inf\n" : " -Inf\n", f);
	else if (fabs(v) < 9e15 && v == (double)(int64_t)v)
		fprintf(f, " %" PRId64 "\n", (int64_t)v);
	else {
		for (int digits = 15; digits <= 17; digits++) {
			snprintf(text, sizeof(text), "%.*g", digits, v);
			if (strtod(text, NULL) == v)
				break;
		}
		fprintf(f, " %s\n", text);
	}
}

/* A sample with up to two labels (NULL names: fewer). */
static void sample(FILE *f, const char *name, const char *l1, const char *v1, const char *l2,
		   const char *v2, double v)
{
	fputs(name, f);
	if (l1) {
		fprintf(f, "{%s=\"", l1);
		put_escaped(f, v1, true);
		if (l2) {
			fprintf(f, "\",%s=\"", l2);
			put_escaped(f, v2, true);
		}
		fputs("\"}", f);
	}
	put_value(f, v);
}

static void metrics_jobs(struct monitor *m, FILE *f)
{
	const int64_t *counts = jobs_counts(m->jobs);

	family(f, "asphd_jobs", "gauge", "Jobs in the job store, by state.");
	for (int s = 0; s < JOB_N_STATES; s++)
		sample(f, "asphd_jobs", "state", job_state_name((enum job_state)s), NULL, NULL,
		       (double)counts[s]);
}

static void metrics_instruments(struct monitor *m, FILE *f)
{
	static const char *const states[] = { "idle", "measuring", "paused", "fault" };
	size_t n = instruments_count(m->instruments);

	family(f, "asphd_points_measured_total", "counter",
	       "Points measured since the daemon started, by instrument.");
	for (size_t i = 0; i < n; i++)
		sample(f, "asphd_points_measured_total", "instrument",
		       instruments_get(m->instruments, i)->name, NULL, NULL,
		       (double)jobs_activity(m->jobs, i)->points_measured);
	family(f, "asphd_scan_rate_points_per_second", "gauge",
	       "Points per second of the scan running on the instrument, 0 when none runs.");
	for (size_t i = 0; i < n; i++) {
		const struct instrument_activity *a = jobs_activity(m->jobs, i);
		sample(f, "asphd_scan_rate_points_per_second", "instrument",
		       instruments_get(m->instruments, i)->name, NULL, NULL,
		       a->job && !a->paused && !a->characterizing && isfinite(a->rate) ? a->rate : 0);
	}
	family(f, "asphd_instrument_state", "gauge",
	       "1 for the state the instrument is in (idle, measuring, paused, fault), 0 for the others.");
	for (size_t i = 0; i < n; i++) {
		const char *now = instrument_state_name(jobs_activity(m->jobs, i));
		for (size_t s = 0; s < ARRAY_SIZE(states); s++)
			sample(f, "asphd_instrument_state", "instrument",
			       instruments_get(m->instruments, i)->name, "state", states[s],
			       !strcmp(now, states[s]));
	}
	family(f, "asphd_instrument_locked", "gauge",
	       "1 while an operator holds the instrument's lock.");
	for (size_t i = 0; i < n; i++)
		sample(f, "asphd_instrument_locked", "instrument",
		       instruments_get(m->instruments, i)->name, NULL, NULL,
		       jobs_activity(m->jobs, i)->lock != NULL);
}

/* The families of the sinks, with samples of the configured ones (none
 * without a sink). */
static void metrics_sinks(struct monitor *m, FILE *f)
{
	static const struct {
		const char *name, *help;
	} families[] = {
		{ "asphd_outbox_messages", "Messages waiting in the outbox for the sink." },
		{ "asphd_outbox_held_messages",
		  "Messages the sink refused for good, waiting for the next start." },
		{ "asphd_outbox_oldest_age_seconds",
		  "Age of the oldest message waiting for the sink, 0 when none waits." },
		{ "asphd_sink_up", "1 while the daemon is connected to the sink." },
	};
	int64_t now = now_realtime_ns();
	bool any = false;

	for (int k = 0; k < OUTBOX_N_SINKS; k++)
		any |= m->sinks[k].configured;
	for (size_t i = 0; any && i < ARRAY_SIZE(families); i++) {
		family(f, families[i].name, "gauge", families[i].help);
		for (int k = 0; k < OUTBOX_N_SINKS; k++) {
			enum outbox_sink_kind kind = (enum outbox_sink_kind)k;
			int64_t v = 0, oldest;
			if (!m->sinks[k].configured)
				continue;
			if (i == 3)
				v = m->sinks[k].up;
			else if (!m->outbox)
				v = 0;
			else if (i == 0)
				v = outbox_waiting(m->outbox, kind);
			else if (i == 1)
				v = outbox_held(m->outbox, kind);
			else if ((oldest = outbox_oldest_ns(m->outbox, kind)) > 0)
				v = (int64_t)((now - oldest) / NS_PER_SEC);
			sample(f, families[i].name, "sink", outbox_sink_name(kind), NULL, NULL,
			       (double)v);
		}
	}
}

static void metrics_errors(struct monitor *m, FILE *f)
{
	uint64_t errors = 0;

	for (int p = LOG_EMERG; p <= LOG_ERR; p++)
		errors += log_messages(p);

	family(f, "asphd_errors_total", "counter", "Errors since the daemon started, by kind.");
	for (int k = 0; k < MONITOR_N_ERRORS; k++)
		sample(f, "asphd_errors_total", "kind", error_names[k], NULL, NULL,
		       (double)m->errors[k]);
	family(f, "asphd_log_messages_total", "counter", "Messages logged since the daemon "
	       "started, by level (error: errors and worse; warning).");
	sample(f, "asphd_log_messages_total", "level", "error", NULL, NULL, (double)errors);
	sample(f, "asphd_log_messages_total", "level", "warning", NULL, NULL,
	       (double)log_messages(LOG_WARNING));
}

static void metrics_health(struct monitor *m, FILE *f)
{
	_cleanup_(json_decrefp) json_t *findings = monitor_health(m);
	uint64_t free_mb;

	family(f, "asphd_health_degraded", "gauge",
	       "1 while the check finds the daemon degraded (docs/admin.md, Health), else 0.");
	for (int c = 0; c < N_CHECKS; c++) {
		bool found = false;
		size_t i;
		json_t *v;
		json_array_foreach(findings, i, v)
			found |= !strcmp(json_string_value(json_object_get(v, "check")), check_names[c]);
		sample(f, "asphd_health_degraded", "check", check_names[c], NULL, NULL, found);
	}
	if (dirs_free_mb(m->state_fd, &free_mb) == 0) {
		family(f, "asphd_state_dir_free_bytes", "gauge",
		       "Bytes free for the daemon on the state directory's file system.");
		sample(f, "asphd_state_dir_free_bytes", NULL, NULL, NULL, NULL,
		       (double)free_mb * 1048576.0);
	}
}

/* Descriptors open in this process, the one that reads them left out. */
static int64_t open_fds(void)
{
	DIR *d = opendir("/proc/self/fd");
	int64_t n = -1;         /* (the directory's own) */

	if (!d)
		return -1;
	for (struct dirent *e; (e = readdir(d));)
		n += e->d_name[0] != '.';
	closedir(d);
	return n;
}

/* The process's figures under the names Prometheus's client libraries
 * give them, so that the usual dashboards read them. */
static void metrics_process(struct monitor *m, FILE *f)
{
	long page = sysconf(_SC_PAGESIZE);
	unsigned long long size = 0, resident = 0;
	struct rusage ru;
	struct rlimit rl;
	FILE *statm = fopen("/proc/self/statm", "re");
	int64_t fds = open_fds();

	if (statm && fscanf(statm, "%llu %llu", &size, &resident) == 2) {
		family(f, "process_resident_memory_bytes", "gauge", "Resident memory size in bytes.");
		sample(f, "process_resident_memory_bytes", NULL, NULL, NULL, NULL,
		       (double)resident * (double)page);
		family(f, "process_virtual_memory_bytes", "gauge", "Virtual memory size in bytes.");
		sample(f, "process_virtual_memory_bytes", NULL, NULL, NULL, NULL,
		       (double)size * (double)page);
	}
	if (statm)
		fclose(statm);
	if (fds >= 0) {
		family(f, "process_open_fds", "gauge", "Number of open file descriptors.");
		sample(f, "process_open_fds", NULL, NULL, NULL, NULL, (double)fds);
	}
	if (getrlimit(RLIMIT_NOFILE, &rl) == 0) {
		family(f, "process_max_fds", "gauge", "Maximum number of open file descriptors.");
		sample(f, "process_max_fds", NULL, NULL, NULL, NULL,
		       rl.rlim_cur == RLIM_INFINITY ? INFINITY : (double)rl.rlim_cur);
	}
	if (getrusage(RUSAGE_SELF, &ru) == 0) {
		family(f, "process_cpu_seconds_total", "counter",
		       "Total user and system CPU time spent in seconds.");
		sample(f, "process_cpu_seconds_total", NULL, NULL, NULL, NULL,
		       (double)(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
		       (double)(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) / 1e6);
	}
	family(f, "process_start_time_seconds", "gauge",
	       "Start time of the process since unix epoch in seconds.");
	sample(f, "process_start_time_seconds", NULL, NULL, NULL, NULL,
	       (double)(m->started_ns / NS_PER_SEC));
}

char *monitor_metrics(struct monitor *m, size_t *len)
{
	char *text = NULL;
	FILE *f = m ? open_memstream(&text, len) : NULL;

	if (!f)
		return NULL;
	family(f, "asphd_build_info", "gauge", "The daemon's version: always 1.");
	sample(f, "asphd_build_info", "version", m->version, NULL, NULL, 1);
	metrics_jobs(m, f);
	metrics_instruments(m, f);
	metrics_sinks(m, f);
	metrics_errors(m, f);
	metrics_health(m, f);
	metrics_process(m, f);
	if (fclose(f) != 0) {
		free(text);
		return NULL;
	}
	return text;
}
