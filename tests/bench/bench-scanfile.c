/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Recorded scans: points per second through the writer (encode, CRC,
 * write, fdatasync per block) and the reader (read, CRC, decode), each
 * against plain write()+fdatasync() / pread() of the same number of bytes
 * in the same block sizes, measured in the same run.
 */
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph/scanfile.h"
#include "bench-common.h"

#define BLOCK 10000

struct ctx {
	size_t batch;           /* points per append call */
	char path[64];
	char raw_path[64];
	size_t n;
	struct asph_scanfile_point *pts;
	uint8_t *bytes;
	uint64_t read_points;
};

static const struct asph_scanfile_header_info info = {
	"{\"type\":\"even_asphere\",\"R\":20.097,\"k\":-1,\"aperture_diameter\":40}",
	"{\"method\":\"fermat\",\"density\":{\"kind\":\"points\",\"value\":1}}",
	"{\"probe\":{\"driver\":\"mock\"}}",
	NULL,
};

static void run_writer(void *p)
{
	struct ctx *c = p;
	struct asph_scanfile_writer_options o = { .flags = ASPH_SCANFILE_OVERWRITE };
	struct asph_scanfile_writer *w;
	struct asph_error err;

	if (asph_scanfile_writer_create(c->path, &info, &o, &w, &err) < 0)
		exit(1);
	for (size_t i = 0; i < c->n; i += c->batch) {
		size_t k = c->n - i < c->batch ? c->n - i : c->batch;
		if (asph_scanfile_writer_append(w, c->pts + i, k, &err) < 0)
			exit(1);
	}
	if (asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED, NULL, &err) < 0)
		exit(1);
}

static void run_raw_write(void *p)
{
	struct ctx *c = p;
	size_t block = (size_t)BLOCK * ASPH_SCANFILE_RECORD_SIZE;
	size_t total = c->n * ASPH_SCANFILE_RECORD_SIZE;
	int fd = open(c->raw_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);

	if (fd < 0)
		exit(1);
	for (size_t off = 0; off < total; off += block) {
		size_t k = total - off < block ? total - off : block;
		if (write(fd, c->bytes + off, k) != (ssize_t)k || fdatasync(fd) < 0)
			exit(1);
	}
	close(fd);
}

static void run_reader(void *p)
{
	struct ctx *c = p;
	struct asph_scanfile_reader *r;
	const struct asph_scanfile_point *pts;
	struct asph_error err;
	size_t n;

	c->read_points = 0;
	if (asph_scanfile_reader_open(c->path, &r, &err) < 0)
		exit(1);
	while (asph_scanfile_reader_next(r, &pts, &n, &err) > 0)
		c->read_points += n;
	asph_scanfile_reader_free(r);
}

static void run_raw_read(void *p)
{
	struct ctx *c = p;
	size_t block = (size_t)BLOCK * ASPH_SCANFILE_RECORD_SIZE;
	size_t total = c->n * ASPH_SCANFILE_RECORD_SIZE;
	int fd = open(c->raw_path, O_RDONLY | O_CLOEXEC);

	if (fd < 0)
		exit(1);
	for (size_t off = 0; off < total; off += block) {
		size_t k = total - off < block ? total - off : block;
		if (pread(fd, c->bytes + off, k, (off_t)off) != (ssize_t)k)
			exit(1);
	}
	close(fd);
}

int main(void)
{
	struct ctx c = { .n = bench_size(2000000) };
	int miss = 0;

	snprintf(c.path, sizeof(c.path), "/tmp/bench-scanfile-%d.scan", (int)getpid());
	snprintf(c.raw_path, sizeof(c.raw_path), "/tmp/bench-scanfile-%d.raw", (int)getpid());
	c.pts = malloc(c.n * sizeof(*c.pts));
	c.bytes = malloc(c.n * ASPH_SCANFILE_RECORD_SIZE);
	if (!c.pts || !c.bytes)
		return 1;
	for (size_t i = 0; i < c.n; i++) {
		double t = 0.001 * (double)i;
		c.pts[i] = (struct asph_scanfile_point){
			.plan_index = i, .x = 18 * cos(t), .y = 18 * sin(t),
			.z = 0.3 * t, .raw = 0.01 * t, .t_ns = 1000 * i,
		};
	}
	memset(c.bytes, 0x5a, c.n * ASPH_SCANFILE_RECORD_SIZE);

	printf("%zu points, %d per block\n", c.n, BLOCK);
	double raw_w = bench_median(run_raw_write, &c, 3);
	/* a streaming probe delivers a few hundred points at a time, a
	 * point-by-point executor one */
	c.batch = 250;
	double w = bench_median(run_writer, &c, 3);
	c.batch = 1;
	double w1 = bench_median(run_writer, &c, 3);
	bench_report("baseline: write+fdatasync, same bytes", raw_w, raw_w, 0);
	miss |= bench_report("writer, 250 points per append", w, raw_w, 2.0);
	printf("  writer: %.2f M points/s\n", (double)c.n / w * 1e-6);
	miss |= bench_report("writer, 1 point per append", w1, raw_w, 3.0);
	printf("  writer: %.2f M points/s\n", (double)c.n / w1 * 1e-6);

	double raw_r = bench_median(run_raw_read, &c, 3);
	double r = bench_median(run_reader, &c, 3);
	if (c.read_points != c.n)
		return 1;
	bench_report("baseline: pread, same bytes", raw_r, raw_r, 0);
	miss |= bench_report("reader: read, CRC, decode", r, raw_r, 4.0);
	printf("  reader: %.2f M points/s\n", (double)c.n / r * 1e-6);

	unlink(c.path);
	unlink(c.raw_path);
	free(c.pts);
	free(c.bytes);
	return miss;
}
