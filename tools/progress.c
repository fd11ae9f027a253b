/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <math.h>
#include <unistd.h>

#include "progress.h"
#include "util-time.h"

/* Quiet for the first second: a short operation draws nothing. */
#define PROGRESS_DELAY_NS NS_PER_SEC
/* At most five redraws a second. */
#define PROGRESS_REDRAW_NS (200 * NS_PER_MS)

void progress_start(struct progress *p, const char *what, const char *unit, bool quiet)
{
	*p = (struct progress){
		.out = stderr, .on = !quiet && isatty(STDERR_FILENO), .what = what, .unit = unit,
		.start_ns = now_monotonic_ns(),
	};
}

const char *progress_duration(double s, char *buf, size_t size)
{
	if (!(s >= 0) || !isfinite(s) || s > 1e9)
		snprintf(buf, size, "--:--");
	else if (s < 3600)
		snprintf(buf, size, "%d:%02d", (int)s / 60, (int)s % 60);
	else
		snprintf(buf, size, "%d:%02d:%02d", (int)s / 3600, (int)s / 60 % 60, (int)s % 60);
	return buf;
}

int progress_show(void *data, size_t done, size_t total)
{
	struct progress *p = data;
	uint64_t now = now_monotonic_ns();
	double elapsed = (double)(now - p->start_ns) / NS_PER_SEC;
	double counted, rate;
	char t[32];

	if (!p->counting) {
		p->counting = true;
		p->first_ns = now;
		p->first_done = done;
	}
	counted = (double)(now - p->first_ns) / NS_PER_SEC;
	rate = counted > 0 && done > p->first_done ? (double)(done - p->first_done) / counted : 0;
	if (!p->on || now - p->start_ns < (uint64_t)PROGRESS_DELAY_NS)
		return 0;
	if (total > 0 && done >= total) {
		/* the last step: no rate or time left to tell */
		fprintf(p->out, "\r\033[K%s: %zu %s done, finishing (%s so far)", p->what, done,
			p->unit, progress_duration(elapsed, t, sizeof(t)));
		goto drawn;
	}
	if (p->drawn && now - p->drawn_ns < (uint64_t)PROGRESS_REDRAW_NS)
		return 0;
	progress_duration(rate > 0 && total > 0 ? (double)(total - (done < total ? done : total)) / rate
						: NAN, t, sizeof(t));
	if (total > 0 && p->at_most)
		fprintf(p->out, "\r\033[K%s: %zu of at most %zu %s, %.1f %s/s, at most %s left",
			p->what, done, total, p->unit, rate, p->unit, t);
	else if (total > 0)
		fprintf(p->out, "\r\033[K%s: %zu/%zu %s (%d %%), %.1f %s/s, %s left", p->what, done,
			total, p->unit, (int)(100.0 * (double)done / (double)total), rate, p->unit, t);
	else
		fprintf(p->out, "\r\033[K%s: %zu %s, %.1f %s/s, %s so far", p->what, done, p->unit,
			rate, p->unit, progress_duration(elapsed, t, sizeof(t)));
drawn:
	fflush(p->out);
	p->drawn = true;
	p->drawn_ns = now;
	return 0;
}

struct asph_progress progress_hook(struct progress *p)
{
	return (struct asph_progress){ .fn = progress_show, .data = p };
}

void progress_stop(struct progress *p)
{
	if (!p->drawn)
		return;
	fprintf(p->out, "\r\033[K");
	fflush(p->out);
	p->drawn = false;
}
