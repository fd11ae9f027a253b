/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The Monte Carlo's trials on a pool of threads: libasph runs the trials,
 * this file only shares them out and waits. */
#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <unistd.h>

#include "asph-mc/mc-runner.h"

struct pool;

struct pool_worker {
	struct pool *pool;
	struct asph_mc_worker *w;
	pthread_t thread;
	int started;
};

struct pool {
	struct asph_mc *mc;
	int n_workers;
	struct pool_worker *workers;

	/* The block being run, shared with the workers under lock: trials
	 * [next, end) wait, finished of them are done. */
	pthread_mutex_t lock;
	pthread_cond_t work, done;
	size_t next, end, finished;
	int quit, cancel;
};

int asph_mc_default_threads(void)
{
	long cpus = sysconf(_SC_NPROCESSORS_ONLN);

	return cpus > 0 ? (int)(cpus < 256 ? cpus : 256) : 1;
}

static void *worker_main(void *data)
{
	struct pool_worker *pw = data;
	struct pool *p = pw->pool;

	pthread_mutex_lock(&p->lock);
	for (;;) {
		while (!p->quit && (p->cancel || p->next >= p->end))
			pthread_cond_wait(&p->work, &p->lock);
		if (p->quit)
			break;
		size_t t = p->next++;
		pthread_mutex_unlock(&p->lock);
		/* t < end <= the capacity asph_mc_next_block() keeps to */
		(void)asph_mc_run_trials(p->mc, pw->w, t, 1);
		pthread_mutex_lock(&p->lock);
		p->finished++;
		pthread_cond_signal(&p->done);
	}
	pthread_mutex_unlock(&p->lock);
	return NULL;
}

/* Hands trials [p->finished, end) to the workers and waits for them,
 * reporting progress. Trials are taken in order and every one taken
 * finishes, so the trials done are always [0, finished). 1 when
 * cancelled, else 0. */
static int run_block(struct pool *p, size_t end, const struct asph_mc_threads *o)
{
	size_t told = (size_t)-1;

	pthread_mutex_lock(&p->lock);
	p->end = end;
	pthread_cond_broadcast(&p->work);
	while (p->finished < p->next || (p->next < p->end && !p->cancel)) {
		pthread_cond_wait(&p->done, &p->lock);
		size_t done = p->finished;
		if (o->progress) {
			/* the callback runs unlocked: it may take its time */
			pthread_mutex_unlock(&p->lock);
			int stop = o->progress(o->progress_data, done, end);
			pthread_mutex_lock(&p->lock);
			told = done;
			if (stop)
				p->cancel = 1;
		}
	}
	/* The last trials may have finished while the callback ran: the last
	 * count is always told. */
	size_t done = p->finished;
	int cancelled = p->cancel;
	pthread_mutex_unlock(&p->lock);
	if (o->progress && !cancelled && told != done)
		o->progress(o->progress_data, done, end);
	return cancelled;
}

static void pool_stop(struct pool *p)
{
	pthread_mutex_lock(&p->lock);
	p->quit = 1;
	pthread_cond_broadcast(&p->work);
	pthread_mutex_unlock(&p->lock);
	for (int i = 0; i < p->n_workers; i++)
		if (p->workers[i].started)
			pthread_join(p->workers[i].thread, NULL);
}

static void pool_free(struct pool *p)
{
	for (int i = 0; p->workers && i < p->n_workers; i++)
		asph_mc_worker_free(p->workers[i].w);
	free(p->workers);
	pthread_cond_destroy(&p->work);
	pthread_cond_destroy(&p->done);
	pthread_mutex_destroy(&p->lock);
}

/* The workers' state, allocated once for the whole run, then the threads. */
static int pool_start(struct pool *p, struct asph_error *err)
{
	p->workers = calloc((size_t)p->n_workers, sizeof(*p->workers));
	if (!p->workers)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (int i = 0; i < p->n_workers; i++) {
		int r = asph_mc_worker_alloc(p->mc, &p->workers[i].w, err);
		if (r < 0)
			return r;
		p->workers[i].pool = p;
	}
	for (int i = 0; i < p->n_workers; i++) {
		if (pthread_create(&p->workers[i].thread, NULL, worker_main, &p->workers[i]))
			return asph_error_set(err, -EAGAIN, "cannot start a worker thread");
		p->workers[i].started = 1;
	}
	return 0;
}

int asph_mc_run_threads(struct asph_mc *mc, const struct asph_mc_threads *opts,
			struct asph_mc_result *out, struct asph_error *err)
{
	struct asph_mc_threads o = opts ? *opts : (struct asph_mc_threads){ 0 };
	struct pool p = { .mc = mc };
	size_t first, count;
	int r, cancelled = 0;

	if (o.n_threads == 0)
		o.n_threads = asph_mc_default_threads();
	if (o.n_threads < 1 || o.n_threads > 256)
		return asph_error_set(err, -EINVAL, "the number of threads must be 1..256, not %d",
				      o.n_threads);
	p.n_workers = o.n_threads;
	pthread_mutex_init(&p.lock, NULL);
	pthread_cond_init(&p.work, NULL);
	pthread_cond_init(&p.done, NULL);
	r = pool_start(&p, err);
	while (r == 0 && !cancelled && asph_mc_next_block(mc, p.finished, &first, &count))
		cancelled = run_block(&p, first + count, &o);
	pool_stop(&p);
	pool_free(&p);
	if (r < 0)
		return r;
	return asph_mc_finish(mc, p.finished, cancelled, out, err);
}
