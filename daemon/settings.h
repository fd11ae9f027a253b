/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asphd's configuration file (/etc/asphd/asphd.conf, JSON with "//"
 * comments; docs/daemon.md, docs/admin.md):
 * who may operate, where to listen, the limits, and the instruments (the
 * "instruments" member in the drivers' format, docs/drivers.md).
 */
#ifndef ASPHD_SETTINGS_H
#define ASPHD_SETTINGS_H

#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#include "asph/error.h"

struct settings_limits {
	uint32_t max_clients;
	uint32_t max_clients_per_user;  /* per uid; per TCP address */
	uint32_t reserved_clients;      /* of max_clients, for root and operators */
	uint32_t max_request_bytes;     /* one line */
	uint32_t max_response_bytes;    /* the answers to one line */
	uint32_t max_output_bytes;      /* queued to one client */
	uint32_t max_queue;             /* jobs queued, paused or interrupted */
	uint32_t max_plan_points;
	uint32_t max_plan_point_terms;  /* a plan's points times its surface's terms */
	uint32_t max_subscriptions;     /* clients subscribed to events */
	uint32_t max_subscriptions_per_user;
	uint32_t reserved_subscriptions;        /* of max_subscriptions, for operators */
	uint32_t request_timeout_ms;    /* an incomplete request; unread output */
	uint32_t auth_timeout_ms;       /* a TCP client without hello */
	uint32_t idle_timeout_ms;       /* a client without requests; 0: none */
	uint32_t progress_interval_ms;  /* between progress events of a job */
	uint32_t max_label_bytes;
	uint32_t max_measured_bytes;    /* a job's measured data (job.submit) */
	uint32_t min_free_disk_mb;      /* kept free on the state directory */
};

/* The "health" section: when the daemon counts as degraded (monitor.h,
 * docs/admin.md "Health"). */
struct settings_health {
	uint32_t sink_down_s;           /* a sink out of reach this long */
	uint32_t outbox_age_s;          /* a sink's oldest message this old */
};

/* The "mqtt" section: telemetry to a broker (docs/fleet.md). */
struct settings_mqtt {
	char *url;                      /* as written */
	bool tls;                       /* mqtts:// */
	char *host;                     /* its parts ("[...]" of IPv6 taken off) */
	int port;
	char *prefix;                   /* NULL: "asphd/<hostname>" */
	char *client_id;                /* NULL: "asphd-<hostname>-<daemon id, 8>" */
	int qos;                        /* 0, 1, 2 */
	char *credentials_file;         /* NULL: none */
	char *ca_file;                  /* NULL: the system's (mqtts) */
};

/* The "postgres" section: the central results store (docs/fleet.md). */
struct settings_postgres {
	char *conninfo;                 /* a libpq connection string */
	char *password_file;            /* NULL: none (or ~/.pgpass, PGPASSWORD) */
};

struct settings {
	char *source;                   /* the file, or NULL for defaults */
	char *socket_path;
	char *socket_group;             /* NULL: the daemon's group */
	mode_t socket_mode;
	char *operator_group;           /* NULL: only root operates */
	char *tcp_listen;               /* "HOST:PORT" or NULL (off), as written */
	char *tcp_host, *tcp_port;      /* its parts ("[...]" of IPv6 taken off) */
	char *token_file;
	char *http_listen;              /* "HOST:PORT" or NULL (off), as written */
	char *http_host, *http_port;    /* its parts */
	char *http_root;                /* the web page's files (NULL: built in) */
	char **http_allowed_hosts;      /* Host names served, NULL-terminated; NULL: default */
	char *http_trust_proxy;         /* the reverse proxy's address, or NULL */
	char *state_dir;
	struct settings_limits limits;
	struct settings_health health;
	struct settings_mqtt *mqtt;     /* NULL: no MQTT */
	struct settings_postgres *postgres;     /* NULL: no central store */
	/* Instruments: {"instruments": [...]} as JSON text for the drivers'
	 * parser, or NULL for the default single "mock" instrument. */
	char *instruments_json;
	char *text;                     /* the file (comments blanked), to locate errors */
	size_t text_len;
};

/* The state directory without a setting (systemd's StateDirectory=). */
#define SETTINGS_STATE_DIR "/var/lib/asphd"

/* One setting of the configuration file, as its reference gives it
 * (asphd --list-settings, docs/admin.md). */
struct setting_info {
	const char *name;       /* "socket", "limits.max_queue", "mqtt.url" */
	char type[64];          /* what it takes: "path", "integer from 1 to 65536" */
	char fallback[64];      /* its default, for people */
	const char *help;       /* what it does */
};

/* Every setting the file takes, in the reference's order: settings_count()
 * of them, the i-th described into *out. The file is read through the
 * same table. */
size_t settings_count(void);
void settings_describe(size_t i, struct setting_info *out);

/* Called once for every error found (the load goes on where it can). */
typedef void (*settings_error_fn)(const struct asph_error *err, void *data);

/* The comments of the file's text blanked: "//" outside a string, to the
 * end of its line, becomes spaces (the line feed stays), so that JSON's
 * parser reads the rest and every place in the file keeps its line and
 * column. settings_load() does it; the text it keeps (text) is blanked. */
void settings_blank_comments(char *text, size_t len);

/*
 * Loads path (NULL: the defaults). Every problem is reported through
 * report (may be NULL); returns 0 or -EINVAL when there was any, -errno
 * when the file cannot be read. The instruments are checked separately
 * (instruments_load() in instruments.c), since that needs the drivers.
 */
int settings_load(const char *path, struct settings **out,
		settings_error_fn report, void *data);
void settings_free(struct settings *c);

void settings_mqtt_free(struct settings_mqtt *m);
void settings_postgres_free(struct settings_postgres *p);

/* The defaults without a file. */
int settings_defaults(struct settings **out);

/*
 * Points err at the setting field ("token_file", "limits.max_queue",
 * "instruments.[0].probe"): the file with the line and column where it
 * stands, and the field. For errors found after loading (the operator
 * group, the token file, the instruments' drivers).
 */
void settings_locate(const struct settings *s, const char *field, struct asph_error *err);

/* An error found after loading, about field: made (code, the message from
 * fmt), located as settings_locate() does and handed to report (which may
 * be NULL). */
void settings_vreport(const struct settings *s, const char *field, int code,
		      settings_error_fn report, void *data, const char *fmt, va_list ap)
	__attribute__((format(printf, 6, 0)));

#endif
