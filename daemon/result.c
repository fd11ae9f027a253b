/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Worker thread: a job's recorded scan characterized by libasph
 * (asph/characterize.h), as asph replay characterizes it, with the Monte
 * Carlo on this program's threads, and the result files in its folder.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>

#include "asph/characterize.h"
#include "asph/points.h"
#include "asph-driver/instrument.h"
#include "asph-mc/mc-runner.h"
#include "asph-proto.h"
#include "config.h"
#include "dirs.h"
#include "result.h"
#include "runner.h"
#include "util-fs.h"
#include "util-mem.h"

#define STR(x) #x
#define XSTR(x) STR(x)
#define PROTOCOL_VERSION XSTR(PROTO_VERSION_MAJOR) "." XSTR(PROTO_VERSION_MINOR)

/* provenance.software of every result */
#define SOFTWARE_JSON "{\"asphd\": \"" ASPH_VERSION "\", \"libasph\": \"" ASPH_VERSION \
	"\", \"protocol\": \"" PROTOCOL_VERSION "\"}"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_characterization *, asph_characterize_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

/* The recorded scan, mapped read-only from the job's folder. */
struct mapped {
	void *data;
	size_t len;
};

static void unmap(struct mapped *m)
{
	if (m->data && m->data != MAP_FAILED)
		munmap(m->data, m->len);
}

/* The file name of the job's folder (the recorded scan, the measured
 * data), mapped read-only. */
static int map_file(const struct result_source *job, const char *name, struct mapped *m,
		    struct asph_error *err)
{
	_cleanup_close_ int fd = fs_open_beneath(job->dir_fd, name, O_RDONLY, 0);
	struct stat st;

	if (fd < 0)
		return asph_error_set(err, fd, "%s/%s: %s", job->dir, name,
				      fd == -ELOOP ? "a symbolic link: not read" : strerror(-fd));
	if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode) || st.st_size <= 0)
		return asph_error_set(err, -EINVAL, "%s/%s: not a file of data", job->dir, name);
	m->len = (size_t)st.st_size;
	m->data = mmap(NULL, m->len, PROT_READ, MAP_PRIVATE, fd, 0);
	if (m->data == MAP_FAILED) {
		m->data = NULL;
		return asph_error_set(err, -errno, "%s/%s: %s", job->dir, name, strerror(errno));
	}
	return 0;
}

/* The data file name of the job's folder mapped, and its path for
 * messages. */
static int open_data(const struct result_source *job, const char *name, struct mapped *m,
		     char **path, struct asph_error *err)
{
	int r = map_file(job, name, m, err);

	if (r == 0 && asprintf(path, "%s/%s", job->dir, name) < 0) {
		*path = NULL;
		r = asph_error_set(err, -ENOMEM, "out of memory");
	}
	return r;
}

/* The result files, unless the job was cancelled meanwhile. */
static int write_files(const struct result_source *job, const struct asph_characterization *c,
		       const struct asph_characterize_folder *f, char **out,
		       struct asph_error *err)
{
	if (job->cancelled && job->cancelled(job->cancelled_data))
		return -ECANCELED;
	return asph_characterize_write_folder(c, job->dir_fd, f, out, err);
}

/* Between trials: tells the progress; a non-zero answer stops the run. */
static int on_progress(void *data, size_t done, size_t planned)
{
	const struct result_source *job = data;

	if (job->trials)
		job->trials(job->trials_data, done, planned, false);
	return job->cancelled && job->cancelled(job->cancelled_data);
}

/* The Monte Carlo on a thread per online processor (drivers/mc/mc-runner.c),
 * the first block announced before it starts, the trials run after. */
static int run_mc(void *data, struct asph_mc *mc, struct asph_mc_result *out,
		  struct asph_error *err)
{
	const struct result_source *job = data;
	struct asph_mc_threads th = { .progress = on_progress, .progress_data = data };
	int r;

	if (job->trials)
		job->trials(job->trials_data, 0, ASPH_MC_DEFAULT_TRIALS, false);
	r = asph_mc_run_threads(mc, &th, out, err);
	if (r == 0 && job->trials)
		job->trials(job->trials_data, out->n_trials, out->n_trials, true);
	return r;
}

int result_build(const struct result_source *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err)
{
	_cleanup_(asph_characterize_freep) struct asph_characterization *c = NULL;
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *scan = NULL;
	_cleanup_free_ char *path = NULL;
	struct mapped m = { 0 };
	struct asph_characterize_options o = {
		.fit = jp->fit, .outputs = ASPH_CHARACTERIZE_MAP,
		/* docs/characterization.md: N = 200 with the adaptive stop, seed 1 */
		.uncertainty = ic->has_uncertainty ? &ic->uncertainty : NULL,
		.mc = { .seed = 1 }, .run_mc = run_mc, .run_mc_data = (void *)job,
		/* part, lot, serial, operator, label: the job's metadata */
		.run = {
			.program = "asphd " ASPH_VERSION, .lens_name = jp->lens_name,
			.metadata_json = job->metadata, .data_name = RUNNER_SCAN_FILE,
		},
	};
	const struct asph_characterize_folder f = {
		.mode = DIRS_FILE_MODE, .scan_file = RUNNER_SCAN_FILE,
		.software_json = SOFTWARE_JSON, .fit_options_json = jp->fit_json,
		.tolerance_json = jp->tolerance_json,
	};
	int r = open_data(job, RUNNER_SCAN_FILE, &m, &path, err);

	if (r == 0)
		r = asph_scanfile_read_memory(m.data, m.len, path, &scan, err);
	o.run.data = m.data;
	o.run.data_len = m.len;
	if (r == 0)
		r = asph_characterize_alloc(jp->surface, &o, &c, err);
	/* Parsed and hashed (by the characterization's alloc): the file's
	 * pages leave the daemon's memory (they stay in the page cache). */
	if (m.data)
		madvise(m.data, m.len, MADV_DONTNEED);
	/* what the files need of the scan, the characterization keeps; the
	 * records go before the fit */
	if (r == 0)
		r = asph_characterize_scan_take(c, &scan, path, err);
	if (r == 0)
		r = write_files(job, c, &f, out, err);
	unmap(&m);
	return r;
}

int result_build_measured(const struct result_source *job, const struct job_plan *jp,
			  const struct asph_points_read_options *ro, const char *name,
			  char **out, struct asph_error *err)
{
	_cleanup_(asph_characterize_freep) struct asph_characterization *c = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	_cleanup_free_ char *path = NULL;
	struct asph_points_read_info info;
	struct mapped m = { 0 };
	/* as asph fit FILE characterizes it: the lab's instrument that
	 * measured it is not this one, whose uncertainty does not apply */
	struct asph_characterize_options o = {
		.fit = jp->fit, .outputs = ASPH_CHARACTERIZE_MAP,
		.run = {
			.program = "asphd " ASPH_VERSION, .lens_name = jp->lens_name,
			.metadata_json = job->metadata, .data_name = name,
		},
	};
	const struct asph_characterize_folder f = {
		.mode = DIRS_FILE_MODE, .scan_file = name, .software_json = SOFTWARE_JSON,
		.fit_options_json = jp->fit_json, .tolerance_json = jp->tolerance_json,
	};
	int r = open_data(job, name, &m, &path, err);

	if (r == 0)
		r = asph_points_read_memory_as(m.data, m.len, path, ro, &pts, &info, err);
	o.run.data = m.data;
	o.run.data_len = m.len;
	if (r == 0)
		r = asph_characterize_alloc(jp->surface, &o, &c, err);
	if (r == 0)
		r = asph_characterize_points(c, pts, err);
	if (r == 0)
		r = write_files(job, c, &f, out, err);
	unmap(&m);
	return r;
}
