/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A mailbox from a thread to the event loop: fixed-size messages posted on
 * any thread, handed in order on the loop's thread. One eventfd wakes the
 * loop however many messages wait, and a message posted while the loop
 * hands the others is handed at the next wake-up. The daemon's threads (the
 * workers, the MQTT client's, the database writer) report through one each.
 */
#ifndef ASPHD_MAILBOX_H
#define ASPHD_MAILBOX_H

#include <stdbool.h>
#include <stddef.h>

#include <systemd/sd-event.h>

struct mailbox;

struct mailbox_setup {
	sd_event *event;
	size_t size;                    /* of a message */
	/* On the loop's thread: one message, in the order posted. */
	void (*deliver)(void *msg, void *data);
	/* A message that will not be delivered (posted after the mailbox could
	 * not grow, or waiting at mailbox_free()): what it owns is freed
	 * here. May be NULL. */
	void (*drop)(void *msg, void *data);
	/* May be NULL: whether msg replaces last, the newest one waiting
	 * (a progress report that only the newest of matters). */
	bool (*replaces)(const void *last, const void *msg);
	void *data;
};

/* 0, or -errno. */
int mailbox_new(const struct mailbox_setup *setup, struct mailbox **out);
/* Drops what waits. The threads that post must be gone. */
void mailbox_free(struct mailbox *b);
/* Stops the wake-ups, for a thread that cannot be waited for: what it
 * posts still waits, undelivered, until mailbox_free(). */
void mailbox_close(struct mailbox *b);
/* Any thread: a copy of msg, and what it owns, for the loop. 0, or -ENOMEM
 * (msg was dropped). */
int mailbox_post(struct mailbox *b, void *msg);

#endif
