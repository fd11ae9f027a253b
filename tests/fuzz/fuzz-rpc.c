/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asphd's method dispatcher without sockets: a daemon with the default
 * configuration (the mock instrument), its job store in a temporary state
 * directory, small limits, and one local client. Each line of the input is
 * a request; the first byte picks the client's user (root, an operator, or
 * a reader without rights). The queue stays stopped ("queue.start" is left
 * out), so no scan runs while the fuzzer works; every other method runs,
 * with the store's state carried from one input to the next.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <syslog.h>
#include <time.h>
#include <unistd.h>

#include "asph/instrument.h"
#include "asphd.h"
#include "fuzz.h"
#include "log.h"

static struct daemon d;
static struct client cl;
static char state_dir[] = "/tmp/asph-fuzz-rpc-XXXXXX";

/* main.c's function the methods call: the status line for systemd (there
 * is none to tell here). */
void daemon_update_status(struct daemon *dm)
{
	(void)dm;
}

static void teardown(void)
{
	char cmd[64 + sizeof(state_dir)];

	instruments_free(&d);
	asph_config_free(d.instrument_config);
	asph_registry_free(d.registry);
	store_close(d.store);
	settings_free(d.config);
	sd_event_unref(d.event);
	free(cl.out);
	snprintf(cmd, sizeof(cmd), "rm -rf '%s'", state_dir);
	if (system(cmd) != 0)
		fprintf(stderr, "could not remove %s\n", state_dir);
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
	struct asph_error err;
	char db[sizeof(state_dir) + 16];

	asph_error_clear(&err);
	log_setup(LOG_CRIT);
	if (!mkdtemp(state_dir))
		fuzz_die("no temporary directory");
	if (settings_defaults(&d.config) < 0 || sd_event_new(&d.event) < 0)
		fuzz_die("no daemon");
	/* Small limits keep each job.submit fast. */
	d.config->limits.max_plan_points = 4000;
	d.config->limits.max_queue = 32;
	free(d.config->state_dir);
	d.config->state_dir = strdup(state_dir);
	d.state_dir = d.config->state_dir;
	snprintf(db, sizeof(db), "%s/jobs.sqlite", state_dir);
	if (store_open(db, &d.store, &err) < 0 || jobs_init(&d) < 0 ||
	    instruments_load(d.config, &d.registry, &d.instrument_config, &err) < 0 ||
	    instruments_setup(&d, &err) < 0)
		fuzz_die("daemon setup: %s", err.message);
	d.queue_running = false;
	cl.d = &d;
	cl.fd = -1;
	cl.authenticated = true;
	atexit(teardown);
	return 0;
}

static void as_user(uint8_t who)
{
	static gid_t operator_group[1] = { 4242 };

	d.have_operator_group = true;
	d.operator_gid = operator_group[0];
	cl.groups = NULL;
	cl.n_groups = 0;
	switch (who % 3) {
	case 0:
		cl.uid = cl.gid = 0;
		snprintf(cl.name, sizeof(cl.name), "root");
		break;
	case 1:
		cl.uid = cl.gid = 1000;
		cl.groups = operator_group;
		cl.n_groups = 1;
		snprintf(cl.name, sizeof(cl.name), "operator");
		break;
	default:
		cl.uid = cl.gid = 65534;
		snprintf(cl.name, sizeof(cl.name), "reader");
		break;
	}
}

static void handle(const char *line, size_t len)
{
	json_t *msg = proto_parse(line, len, NULL, 0);

	if (!msg)
		return;
	json_t *method = json_is_object(msg) ? json_object_get(msg, "method") : NULL;
	if (!json_is_string(method) || strcmp(json_string_value(method), "queue.start")) {
		json_t *reply = rpc_handle(&cl, msg);
		if (reply) {
			size_t n = 0;
			char *text = proto_dump(reply, &n);
			if (!text)
				fuzz_die("an answer that cannot be encoded");
			free(text);
			json_decref(reply);
		}
	}
	json_decref(msg);
	cl.out_off = cl.out_len = 0;
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
