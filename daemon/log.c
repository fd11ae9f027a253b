/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/stat.h>

#include <systemd/sd-journal.h>

#include "log.h"
#include "util-mem.h"
#include "util-text.h"

static int max_level = LOG_INFO;
static bool to_journal;
/* Messages of each priority (LOG_EMERG..LOG_DEBUG), logged or not: any
 * thread logs. */
static atomic_ullong counts[LOG_DEBUG + 1];

/* A decimal number (digits only, no sign or blanks) ending at *end. */
static int parse_ull(const char *s, char **end, unsigned long long *out)
{
	if (*s < '0' || *s > '9')
		return -EINVAL;
	errno = 0;
	*out = strtoull(s, end, 10);
	return errno ? -errno : 0;
}

/* JOURNAL_STREAM is "DEVICE:INODE", both decimal (systemd.exec(5)). */
static int parse_journal_stream(const char *e, unsigned long long *dev, unsigned long long *ino)
{
	char *end;

	if (parse_ull(e, &end, dev) < 0 || *end != ':' ||
	    parse_ull(end + 1, &end, ino) < 0 || *end)
		return -EINVAL;
	return 0;
}

/* True when stderr is the journal stream systemd set up for us. */
static bool stderr_is_journal(void)
{
	const char *e = getenv("JOURNAL_STREAM");
	unsigned long long dev, ino;
	struct stat st;

	if (!e)
		return false;
	if (parse_journal_stream(e, &dev, &ino) < 0) {
		fprintf(stderr, "asphd: JOURNAL_STREAM=\"%.64s\" is not DEVICE:INODE; "
			"logging to stderr as text\n", e);
		return false;
	}
	if (fstat(2, &st) < 0)
		return false;
	return st.st_dev == dev && st.st_ino == ino;
}

uint64_t log_messages(int priority)
{
	return priority >= 0 && priority <= LOG_DEBUG ? atomic_load(&counts[priority]) : 0;
}

void log_setup(int max_priority)
{
	max_level = max_priority;
	to_journal = stderr_is_journal();
}

/*
 * A message may carry what users sent (a label, a lock's reason, a token's
 * name, a peer's text): its control characters are written as escapes, so
 * that no one can forge a line of the log or act on the terminal that
 * shows it.
 */
void log_job(int priority, int64_t job, const char *fmt, ...)
{
	char text[1024];
	_cleanup_free_ char *escaped = NULL;
	const char *msg = text;
	va_list ap;

	if (priority >= 0 && priority <= LOG_DEBUG)
		atomic_fetch_add(&counts[priority], 1);
	if (priority > max_level)
		return;
	va_start(ap, fmt);
	vsnprintf(text, sizeof(text), fmt, ap);
	va_end(ap);
	if (text_has_controls(text) && (escaped = text_escape_controls(text, false)))
		msg = escaped;
	if (to_journal) {
		if (job > 0)
			sd_journal_send("MESSAGE=%s", msg, "PRIORITY=%d", priority,
					"ASPHD_JOB_ID=%" PRId64, job,
					"SYSLOG_IDENTIFIER=asphd", NULL);
		else
			sd_journal_send("MESSAGE=%s", msg, "PRIORITY=%d", priority,
					"SYSLOG_IDENTIFIER=asphd", NULL);
		return;
	}
	if (job > 0)
		fprintf(stderr, "asphd: job %" PRId64 ": %s\n", job, msg);
	else
		fprintf(stderr, "asphd: %s\n", msg);
}
