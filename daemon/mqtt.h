/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The link to an MQTT broker (libmosquitto). The network is libmosquitto's
 * on a thread of its own: it connects (the name resolved, TCP, TLS, the
 * handshake), keeps the connection, and reconnects with a growing delay
 * (1 s doubling to 30 s), so nothing here blocks the event loop. The loop
 * publishes (mosquitto_publish() only queues), and learns on the loop's
 * thread, through an eventfd, which publications were acknowledged (QoS 1
 * and 2: the broker's PUBACK or PUBCOMP; QoS 0: written to the socket) and
 * when the link goes up or down. It never learns it from a callback on
 * libmosquitto's thread.
 *
 * What publications wait for the broker is counted (mqtt_pending()): a
 * caller that may drop (progress) asks it first; one that may not (the
 * outbox) keeps its messages in the store and hands a bounded window.
 *
 * Event loop thread (mqtt_thread() excepted, which is libmosquitto's).
 */
#ifndef ASPHD_MQTT_H
#define ASPHD_MQTT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <systemd/sd-event.h>

#include "asph/error.h"
#include "settings.h"

/* What the credentials file holds (JSON, private to the daemon's user):
 * {"username": ..., "password": ..., "certfile": ..., "keyfile": ...},
 * each member optional but a password needs a username, and a client
 * certificate needs its key. */
struct mqtt_credentials {
	char *username, *password;
	char *certfile, *keyfile;
};

/*
 * Reads s->mqtt's credentials file (owned by the user running this,
 * readable by it only) and checks that its files and the CA file exist;
 * every problem is reported (settings_locate()'d to the setting). 0, or
 * -EINVAL when there was any. Nothing to check: 0 with *out cleared.
 */
int mqtt_credentials_load(const struct settings *s, struct mqtt_credentials *out,
			  settings_error_fn report, void *data);
void mqtt_credentials_clear(struct mqtt_credentials *c);

struct mqtt_setup {
	sd_event *event;
	const struct settings_mqtt *cfg;
	const struct mqtt_credentials *credentials;
	const char *client_id;
	const char *will_topic;         /* the last will: retained */
	const char *will_payload;
	/* On the loop's thread: the publication of tag was acknowledged
	 * (tags > 0 only); the link went up or down (why: the broker's or
	 * the network's reason when down). */
	void (*acked)(void *data, int64_t tag);
	void (*link)(void *data, bool up, const char *why);
	void *data;
};

struct mqtt;

int mqtt_new(const struct mqtt_setup *setup, struct mqtt **out, struct asph_error *err);
/*
 * Publishes goodbye (retained, as the will's topic) if connected and waits
 * up to 2 s for it to go out, disconnects, and frees. goodbye may be NULL.
 */
void mqtt_free(struct mqtt *m, const char *goodbye);

/*
 * Queues a publication; tag > 0 is told to acked() once the broker has it.
 * -ENOTCONN while the link is down (nothing queued), -ENOMEM, -EINVAL.
 */
int mqtt_publish(struct mqtt *m, const char *topic, const char *payload, int qos, bool retain,
		 int64_t tag);
bool mqtt_up(const struct mqtt *m);
/* Publications queued and not yet acknowledged. */
size_t mqtt_pending(const struct mqtt *m);

#endif
