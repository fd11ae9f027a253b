/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Logging: to the journal with structured fields when stderr is connected
 * to it (JOURNAL_STREAM), else lines on stderr.
 */
#ifndef ASPHD_LOG_H
#define ASPHD_LOG_H

#include <inttypes.h>
#include <stdint.h>
#include <syslog.h>

void log_setup(int max_priority);

/* The messages of priority since the start, whether logged or left out
 * by the level. */
uint64_t log_messages(int priority);

/* job may be 0 (no job); it becomes the JOB_ID field. */
void log_job(int priority, int64_t job, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));

#define log_error(...) log_job(LOG_ERR, 0, __VA_ARGS__)
#define log_warning(...) log_job(LOG_WARNING, 0, __VA_ARGS__)
#define log_notice(...) log_job(LOG_NOTICE, 0, __VA_ARGS__)
#define log_info(...) log_job(LOG_INFO, 0, __VA_ARGS__)
#define log_debug(...) log_job(LOG_DEBUG, 0, __VA_ARGS__)

#endif
