/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A line device's dialogue: the connection, commands and their replies,
 * the profile's operations step by step, device errors in the device's
 * own words, and what a stage does when an operation fails (stop, over a
 * new connection when the old one was lost). Internal to drivers/line/.
 */
#ifndef ASPH_LINE_DIALOGUE_H
#define ASPH_LINE_DIALOGUE_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "asph-driver/driver.h"
#include "link.h"
#include "profile.h"
#include "protocol.h"

struct asph_device {
	atomic_bool stop;
	pthread_mutex_t lock;           /* t and stopping, against stop() */
	struct transport *t;            /* NULL while disconnected */
	bool stopping;                  /* a new connection made to stop the stage:
					 * stop() leaves it alone */
	struct line_link_params lp;
	char host[256], path[256];
	struct line_profile prof;
	struct line_reader rd;
	struct line_vars vars;
	char ids[3][16];
	unsigned reply_ms;              /* the longest wait for one reply */
	bool reconnect, stage;
	unsigned reconnect_ms;          /* connecting, or the port coming back */
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

/* "host:port" or the serial port, for messages. */
const char *line_dev_name(const struct asph_device *d, char *buf, size_t size);

/* Opens the link (a stop() that came meanwhile cancels it at once). */
int line_dev_connect(struct asph_device *d, unsigned timeout_ms, struct asph_error *err);
void line_dev_drop(struct asph_device *d);

/* Before an operation: stopped refuses, a link lost earlier is made again
 * (with the profile's connect sequence). */
int line_dev_ready(struct asph_device *d, struct asph_error *err);

/*
 * Runs an operation of the profile; steps that name an axis run for each
 * axis of mask in turn. m collects what the replies carried; *oor is set
 * when a reading matched the profile's out-of-range pattern. Errors name
 * the operation, and the axis for a step that names one.
 */
int line_run_op(struct asph_device *d, enum line_op_id id, unsigned mask, struct line_match *m,
		bool *oor, uint64_t deadline, unsigned timeout_ms, struct asph_error *err);

/* Sends cmd (NULL: none, wait for a line the device sends by itself) and
 * matches its reply against pattern or range (an out-of-range reading). */
int line_query(struct asph_device *d, const char *cmd, const char *pattern, const char *range,
	       struct line_match *m, bool *oor, uint64_t deadline, struct asph_error *err);

/*
 * Ends a stage operation that failed with r: the stop operation goes out
 * (directly, even after stop()); a lost connection is made again to send
 * it (TCP connects, a serial port is opened again once its device is
 * back) and the message says whether the stage was stopped. r returned.
 */
int line_dev_finish(struct asph_device *d, int r, struct asph_error *err);

#endif
