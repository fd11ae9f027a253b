/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asphd's methods without sockets: the modules of a daemon with the
 * default configuration (the mock instrument), its job store in a
 * temporary state directory, small limits, and one session. Each line of
 * the input is a request, a notification or a batch; the first byte picks
 * the session's user (root, an operator, or a reader without rights). The
 * queue stays stopped (a line that would start it is left out), so no scan
 * runs while the fuzzer works; every other method runs, with the store's
 * state carried from one input to the next.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <syslog.h>
#include <unistd.h>

#include "asph-proto.h"
#include "fuzz.h"
#include "log.h"
#include "rpc.h"

static struct {
	struct settings *settings;
	sd_event *event;
	struct events *events;
	struct instruments *instruments;
	struct access *access;
	struct jobs *jobs;
	struct rpc *rpc;
	struct rpc_session session;
} fz;
static gid_t operator_group[1];
static char state_dir[] = "/tmp/asph-fuzz-rpc-XXXXXX";

static void teardown(void)
{
	char cmd[64 + sizeof(state_dir)];

	rpc_session_close(fz.rpc, &fz.session);
	rpc_free(fz.rpc);
	jobs_free(fz.jobs);
	events_free(fz.events);
	access_free(fz.access);
	instruments_free(fz.instruments);
	settings_free(fz.settings);
	sd_event_unref(fz.event);
	snprintf(cmd, sizeof(cmd), "rm -rf '%s'", state_dir);
	if (system(cmd) != 0)
		fprintf(stderr, "could not remove %s\n", state_dir);
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
	struct job_actor root = { .uid = 0, .name = "root" };
	struct asph_error err;

	asph_error_clear(&err);
	log_setup(LOG_CRIT);
	if (!mkdtemp(state_dir))
		fuzz_die("no temporary directory");
	if (settings_defaults(&fz.settings) < 0 || sd_event_new(&fz.event) < 0 ||
	    events_new(&fz.events) < 0)
		fuzz_die("no daemon");
	/* Small limits keep each job.submit fast. The group root (gid 0)
	 * operates: the operator below is in it, the reader is not. */
	fz.settings->limits.max_plan_points = 4000;
	fz.settings->limits.max_queue = 32;
	fz.settings->operator_group = strdup("root");
	operator_group[0] = 0;
	if (instruments_load(fz.settings, &fz.instruments, &err) < 0 ||
	    access_load(fz.settings, &fz.access, NULL, NULL) < 0 ||
	    jobs_new(&(struct jobs_setup){
			.event = fz.event, .state_dir = state_dir, .instruments = fz.instruments,
			.events = fz.events, .limits = &fz.settings->limits,
		     }, &fz.jobs, &err) < 0 ||
	    jobs_queue_stop(fz.jobs, false, &root, &err) < 0 ||
	    rpc_new(&(struct rpc_setup){
			.event = fz.event, .jobs = fz.jobs, .instruments = fz.instruments,
			.events = fz.events, .access = fz.access, .limits = &fz.settings->limits,
		    }, &fz.rpc) < 0)
		fuzz_die("daemon setup: %s", err.message);
	fz.session.authenticated = true;
	rpc_session_open(fz.rpc, &fz.session);
	atexit(teardown);
	return 0;
}

static void as_user(uint8_t who)
{
	struct peer *p = &fz.session.peer;

	p->groups = NULL;
	p->n_groups = 0;
	switch (who % 3) {
	case 0:
		p->uid = p->gid = 0;
		snprintf(p->name, sizeof(p->name), "root");
		break;
	case 1:
		p->uid = p->gid = 1000;
		p->groups = operator_group;
		p->n_groups = 1;
		snprintf(p->name, sizeof(p->name), "operator");
		break;
	default:
		p->uid = p->gid = 65534;
		snprintf(p->name, sizeof(p->name), "reader");
		break;
	}
}

static bool starts_queue(const json_t *msg)
{
	const json_t *method = json_is_object(msg) ? json_object_get(msg, "method") : NULL;

	return json_is_string(method) && !strcmp(json_string_value(method), "queue.start");
}

/* A line that would start the queue, alone or in a batch. */
static bool starts_scans(const char *line, size_t len)
{
	json_t *msg = proto_parse(line, len, NULL), *e;
	bool found = starts_queue(msg);
	size_t i;

	if (json_is_array(msg))
		json_array_foreach(msg, i, e)
			found = found || starts_queue(e);
	json_decref(msg);
	return found;
}

static void handle(const char *line, size_t len)
{
	json_t *reply;
	size_t n = 0;
	char *text;

	if (starts_scans(line, len))
		return;
	reply = rpc_handle_line(fz.rpc, &fz.session, line, len);
	if (!reply)
		return;
	text = proto_dump(reply, &n);
	if (!text)
		fuzz_die("an answer that cannot be encoded");
	free(text);
	json_decref(reply);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	if (size == 0)
		return 0;
	as_user(data[0]);
	const char *text = (const char *)data + 1, *end = text + size - 1;
	while (text < end) {
		const char *nl = memchr(text, '\n', (size_t)(end - text));
		size_t len = nl ? (size_t)(nl - text) : (size_t)(end - text);
		if (len <= PROTO_DEFAULT_MAX_LINE)
			handle(text, len);
		text += len + 1;
	}
	return 0;
}
