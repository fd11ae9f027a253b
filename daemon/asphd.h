/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asphd's shared state. One event loop thread owns everything here; the
 * worker threads of the instruments talk to it only through runner.h.
 */
#ifndef ASPHD_H
#define ASPHD_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/types.h>

#include <jansson.h>
#include <systemd/sd-event.h>

#include "asph-proto.h"
#include "settings.h"
#include "runner.h"
#include "store.h"

struct asph_registry;
struct asph_config;

/* Event classes a client subscribes to. */
enum {
	EVENT_JOB = 1u << 0,            /* job.state */
	EVENT_PROGRESS = 1u << 1,       /* job.progress */
	EVENT_INSTRUMENT = 1u << 2,     /* instrument.state, instrument.fault */
	EVENT_QUEUE = 1u << 3,          /* queue.state */
};

struct client {
	struct daemon *d;
	struct client *next, *prev;
	uint64_t serial;
	int fd;
	sd_event_source *io;
	sd_event_source *timeout;       /* an incomplete request waits */
	struct proto_lines in;
	char *out;                      /* pending output */
	size_t out_off, out_len, out_cap;
	bool tcp;
	bool authenticated;             /* unix peers always; tcp by token */
	bool closing;                   /* flush what is queued, then close */
	bool eof;
	uid_t uid;
	gid_t gid;
	pid_t pid;
	gid_t *groups;                  /* supplementary groups of the peer */
	int n_groups;
	char name[64];                  /* user name, or "uid N" */
	unsigned events;                /* EVENT_* subscribed */
	int64_t event_job;              /* 0: every job */
};

struct instrument {
	struct daemon *d;
	char *name;
	json_t *description;            /* drivers, options (instrument.list) */
	struct runner *runner;
	int64_t job;                    /* running or paused job, 0 if none */
	bool paused;
	char *fault;                    /* last driver fault, or NULL */
	/* Live progress of the current job. */
	int64_t done, total;
	double rate, eta_s;
	uint64_t last_progress_store_ns;
};

struct daemon {
	sd_event *event;
	const char *config_path;
	struct settings *config;
	const char *socket_override;
	const char *state_override;
	char *state_dir;

	struct asph_registry *registry;
	struct asph_config *instrument_config;
	struct instrument *instruments;
	size_t n_instruments;

	struct store *store;
	bool queue_running;
	bool shutting_down;
	int exit_code;

	/* listeners */
	int unix_fd, tcp_fd;
	bool unix_activated;            /* from systemd: do not unlink */
	char *socket_path;
	sd_event_source *unix_src, *tcp_src;
	gid_t operator_gid;
	bool have_operator_group;
	char *token;                    /* TCP token, or NULL */

	struct client *clients;
	struct client *dead;            /* dropped, freed by the reaper */
	sd_event_source *reaper;
	size_t n_clients, n_subscribed;
	uint64_t next_serial;

	int64_t counts[JOB_N_STATES];   /* jobs per state */
	uint64_t started_usec;          /* CLOCK_MONOTONIC */
	uint64_t requests;
	char status_text[128];
};

/* ---- main.c */
void daemon_update_status(struct daemon *d);

/* ---- server.c: listeners and clients */
int server_listen(struct daemon *d);
void server_close(struct daemon *d);
void client_free(struct client *c);
/* Queues a message to one client; drops the client when its output
 * buffer would pass the limit. Returns 0 or -ECONNRESET (dropped). */
int client_send(struct client *c, const json_t *msg);
/* Sends a notification to every client subscribed to class (and, for job
 * events, to that job). */
void server_broadcast(struct daemon *d, unsigned class, int64_t job,
		      const char *method, json_t *params);

/* ---- rpc.c: methods */
/* Handles one request object; returns the response or NULL (a
 * notification). */
json_t *rpc_handle(struct client *c, json_t *msg);
bool client_is_operator(const struct client *c);

/* ---- jobs.c: the queue */
struct submit_spec;
int jobs_init(struct daemon *d);
void jobs_schedule(struct daemon *d);
json_t *job_to_json(struct daemon *d, const struct job_record *j);
struct instrument *instrument_find(struct daemon *d, const char *name);
struct instrument *instrument_of_job(struct daemon *d, int64_t id);
void jobs_runner_report(struct instrument *in, const struct runner_report *rep);
int jobs_set_state(struct daemon *d, struct job_record *j, enum job_state s,
		   const char *reason, int64_t actor);
/* Stops every scan at a safe point and waits for the workers. */
void jobs_shutdown(struct daemon *d);

/* ---- instruments.c */
/* The driver registry and the instruments of cfg (the mock when none). */
int instruments_load(const struct settings *cfg,
		     struct asph_registry **reg, struct asph_config **out,
		     struct asph_error *err);
int instruments_setup(struct daemon *d, struct asph_error *err);
void instruments_free(struct daemon *d);
json_t *instrument_to_json(struct instrument *in);
const char *instrument_state(const struct instrument *in);
json_t *drivers_to_json(struct daemon *d);

#endif
