/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Zygo .datx (HDF5, libhdf5): the first map of the group /Data/Surface,
 * a rows x columns dataset whose attributes give its invalid value ("No
 * Data") and its converters: "X Converter" and "Y Converter" the spacing
 * (Parameters[1] in their BaseUnit), "Z Converter" the unit of the values
 * (a length, or Fringes: Parameters[1] the wavelength, [2] the
 * interferometric scale factor, [3] the obliquity factor). Row 0 is the
 * top one. */
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <hdf5.h>

#include "fileio.h"
#include "readers.h"
#include "util-mem.h"
#include "util-time.h"

#define M_TO_MM 1000.0
#define SURFACE_GROUP "/Data/Surface"
/* No HDF5 filter that Zygo's writers use packs more than about 1000
 * values into a byte: a map announcing more is refused before it is read. */
#define MAX_VALUES_PER_BYTE 1100

struct datx {
	const char *source;
	struct asph_error *err;
	hid_t file, set;
	char name[128];     /* the map's dataset, for messages */
};

static int datx_error(struct datx *x, int code, const char *field, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));
static int datx_error(struct datx *x, int code, const char *field, const char *fmt, ...)
{
	char msg[400];
	va_list ap;

	va_start(ap, fmt);
	vsnprintf(msg, sizeof(msg), fmt, ap);
	va_end(ap);
	return asph_error_set_at(x->err, code, x->source, 0, 0, field, "datx: %s", msg);
}

/* The first dataset of the group, by name. */
static herr_t first_dataset(hid_t group, const char *name, const H5L_info_t *info, void *data)
{
	char *out = data;
	hid_t d;

	/* soft and external links could name other files: not followed */
	if (info->type != H5L_TYPE_HARD || (d = H5Dopen2(group, name, H5P_DEFAULT)) < 0)
		return 0;
	H5Dclose(d);
	snprintf(out, 128, "%s", name);
	return 1;
}

static int open_map(struct datx *x)
{
	char first[128] = "";
	hsize_t idx = 0;

	if (H5Lexists(x->file, "/Data", H5P_DEFAULT) <= 0 ||
	    H5Lexists(x->file, SURFACE_GROUP, H5P_DEFAULT) <= 0)
		return datx_error(x, -EINVAL, SURFACE_GROUP, "the file has no group %s (not a Zygo .datx)",
				  SURFACE_GROUP);
	hid_t g = H5Gopen2(x->file, SURFACE_GROUP, H5P_DEFAULT);
	if (g < 0)
		return datx_error(x, -EINVAL, SURFACE_GROUP, "the group cannot be opened");
	H5Literate(g, H5_INDEX_NAME, H5_ITER_INC, &idx, first_dataset, first);
	if (first[0])
		x->set = H5Dopen2(g, first, H5P_DEFAULT);
	H5Gclose(g);
	snprintf(x->name, sizeof(x->name), "%s/%s", SURFACE_GROUP, first);
	if (!first[0] || x->set < 0)
		return datx_error(x, -EINVAL, SURFACE_GROUP, "the group holds no map");
	/* a dataset may keep its values in other files (external storage, a
	 * virtual dataset): only the file's own are read */
	hid_t dcpl = H5Dget_create_plist(x->set);
	bool outside = dcpl < 0 || H5Pget_external_count(dcpl) != 0 ||
		       H5Pget_layout(dcpl) == H5D_VIRTUAL;
	if (dcpl >= 0)
		H5Pclose(dcpl);
	if (outside)
		return datx_error(x, -EINVAL, x->name, "the map keeps its values outside the file");
	return 0;
}

/* A converter's BaseUnit and Parameters (up to 4). */
struct converter {
	char unit[32];
	double p[4];
	size_t np;
};

/* The member of a compound type called name: its index, or -1. */
static int member(hid_t type, const char *name)
{
	return H5Tget_member_index(type, name);
}

static int read_string_member(struct datx *x, hid_t attr, hid_t ftype, const char *attr_name,
			      char *out, size_t size)
{
	int i = member(ftype, "BaseUnit");
	hid_t mt = i >= 0 ? H5Tget_member_type(ftype, (unsigned)i) : -1;
	int r = 0;

	if (mt < 0 || H5Tget_class(mt) != H5T_STRING) {
		if (mt >= 0)
			H5Tclose(mt);
		return datx_error(x, -EINVAL, attr_name, "no string member BaseUnit");
	}
	hid_t st = H5Tcopy(H5T_C_S1);
	if (H5Tis_variable_str(mt) > 0) {
		char *s = NULL;
		H5Tset_size(st, H5T_VARIABLE);
		hid_t ct = H5Tcreate(H5T_COMPOUND, sizeof(char *));
		H5Tinsert(ct, "BaseUnit", 0, st);
		if (H5Aread(attr, ct, &s) < 0)
			r = datx_error(x, -EINVAL, attr_name, "BaseUnit cannot be read");
		else
			snprintf(out, size, "%s", s ? s : "");
		if (s) {
			hid_t space = H5Screate(H5S_SCALAR);
			H5Dvlen_reclaim(ct, space, H5P_DEFAULT, &s);
			H5Sclose(space);
		}
		H5Tclose(ct);
	} else {
		size_t n = H5Tget_size(mt);
		char *buf = n < 4096 ? calloc(1, n + 1) : NULL;
		H5Tset_size(st, n);
		hid_t ct = H5Tcreate(H5T_COMPOUND, n);
		H5Tinsert(ct, "BaseUnit", 0, st);
		if (!buf || H5Aread(attr, ct, buf) < 0)
			r = datx_error(x, -EINVAL, attr_name, "BaseUnit cannot be read");
		else
			snprintf(out, size, "%s", buf);
		free(buf);
		H5Tclose(ct);
	}
	H5Tclose(st);
	H5Tclose(mt);
	return r;
}

static int read_parameters(struct datx *x, hid_t attr, hid_t ftype, const char *attr_name,
			   struct converter *c)
{
	int i = member(ftype, "Parameters");
	hid_t mt = i >= 0 ? H5Tget_member_type(ftype, (unsigned)i) : -1;
	hsize_t dim = 0;
	int r = 0;

	c->np = 0;
	if (mt < 0)
		return 0;
	if (H5Tget_class(mt) == H5T_ARRAY && H5Tget_array_ndims(mt) == 1)
		H5Tget_array_dims2(mt, &dim);
	H5Tclose(mt);
	if (dim == 0)
		return datx_error(x, -EINVAL, attr_name, "Parameters is not an array of numbers");
	hsize_t n = dim < 4 ? dim : 4, full = dim;
	double *p = full <= 64 ? calloc(full, sizeof(double)) : NULL;
	hid_t at = H5Tarray_create2(H5T_NATIVE_DOUBLE, 1, &full);
	hid_t ct = H5Tcreate(H5T_COMPOUND, full * sizeof(double));
	H5Tinsert(ct, "Parameters", 0, at);
	if (!p || H5Aread(attr, ct, p) < 0)
		r = datx_error(x, -EINVAL, attr_name, "Parameters cannot be read as numbers");
	else
		memcpy(c->p, p, n * sizeof(double));
	c->np = r == 0 ? n : 0;
	free(p);
	H5Tclose(ct);
	H5Tclose(at);
	return r;
}

static int read_converter(struct datx *x, const char *name, struct converter *c)
{
	if (H5Aexists(x->set, name) <= 0)
		return datx_error(x, -EINVAL, name, "the map %s has no attribute '%s'", x->name, name);
	hid_t attr = H5Aopen(x->set, name, H5P_DEFAULT);
	hid_t ftype = attr >= 0 ? H5Aget_type(attr) : -1;
	int r;

	if (ftype < 0 || H5Tget_class(ftype) != H5T_COMPOUND)
		r = datx_error(x, -EINVAL, name, "not a converter (a compound with BaseUnit and Parameters)");
	else if ((r = read_string_member(x, attr, ftype, name, c->unit, sizeof(c->unit))) == 0)
		r = read_parameters(x, attr, ftype, name, c);
	if (ftype >= 0)
		H5Tclose(ftype);
	if (attr >= 0)
		H5Aclose(attr);
	return r;
}

/* A converter's unit in mm; 0 for one that is not a length. */
static double unit_mm(const char *unit)
{
	static const struct { const char *name; double mm; } units[] = {
		{ "Meters", 1000 }, { "MilliMeters", 1 }, { "MicroMeters", 1e-3 },
		{ "NanoMeters", 1e-6 }, { "Angstroms", 1e-7 }, { "Inches", 25.4 },
	};
	for (size_t i = 0; i < ARRAY_SIZE(units); i++)
		if (!strcasecmp(unit, units[i].name))
			return units[i].mm;
	return 0;
}

static int lateral_spacing(struct datx *x, const char *name, double *mm)
{
	struct converter c;
	int r = read_converter(x, name, &c);

	if (r < 0)
		return r;
	double u = unit_mm(c.unit);
	if (u == 0 || c.np < 2 || !(c.p[1] > 0) || !isfinite(c.p[1] * u))
		return datx_error(x, -EINVAL, name,
				  "no lateral resolution (BaseUnit '%s', Parameters[1] %g): the positions are unknown",
				  c.unit, c.np >= 2 ? c.p[1] : NAN);
	*mm = c.p[1] * u;
	return 0;
}

static int height_scale(struct datx *x, double *mm)
{
	struct converter c;
	int r = read_converter(x, "Z Converter", &c);

	if (r < 0)
		return r;
	if (!strcasecmp(c.unit, "Fringes")) {
		if (c.np < 4)
			return datx_error(x, -EINVAL, "Z Converter",
					  "Fringes need the wavelength, scale and obliquity factors in Parameters[1..3]");
		*mm = c.p[1] * c.p[2] * c.p[3] * M_TO_MM;
	} else {
		*mm = unit_mm(c.unit);
	}
	if (*mm == 0 || !isfinite(*mm))
		return datx_error(x, -EINVAL, "Z Converter", "the unit '%s' is not a length", c.unit);
	return 0;
}

static double no_data(struct datx *x)
{
	double v = INFINITY;

	if (H5Aexists(x->set, "No Data") <= 0)
		return v;
	hid_t a = H5Aopen(x->set, "No Data", H5P_DEFAULT);
	hid_t s = a >= 0 ? H5Aget_space(a) : -1;
	hssize_t n = s >= 0 ? H5Sget_simple_extent_npoints(s) : 0;
	double *buf = n >= 1 && n <= 64 ? calloc((size_t)n, sizeof(double)) : NULL;
	if (buf && H5Aread(a, H5T_NATIVE_DOUBLE, buf) >= 0)
		v = buf[0];
	free(buf);
	if (s >= 0)
		H5Sclose(s);
	if (a >= 0)
		H5Aclose(a);
	return v;
}

/* What the decoder hands back through its pipe: this, then (code 0) the
 * map's nx * ny heights, mm, NaN where a node is invalid. */
struct datx_answer {
	int code;               /* 0, or the decoder's error, told in err */
	struct asph_error err;
	size_t nx, ny;
	double dx, dy;          /* spacing, mm */
};

static int read_map(struct datx *x, size_t file_len, struct datx_answer *a, double **out)
{
	hid_t space = H5Dget_space(x->set);
	hsize_t dims[2];
	size_t nodes;
	double zs = 0;

	int nd = space >= 0 ? H5Sget_simple_extent_ndims(space) : -1;
	if (nd == 2)
		H5Sget_simple_extent_dims(space, dims, NULL);
	if (space >= 0)
		H5Sclose(space);
	if (nd != 2)
		return datx_error(x, -EINVAL, x->name, "the map has %d dimensions, not 2", nd);
	H5T_class_t cls = H5T_NO_CLASS;
	hid_t t = H5Dget_type(x->set);
	if (t >= 0) {
		cls = H5Tget_class(t);
		H5Tclose(t);
	}
	if (cls != H5T_FLOAT && cls != H5T_INTEGER)
		return datx_error(x, -EINVAL, x->name, "the map's values are not numbers");
	if (points_map_size((size_t)dims[1], (size_t)dims[0], sizeof(double), &nodes, NULL) < 0 ||
	    nodes / MAX_VALUES_PER_BYTE > file_len)
		return datx_error(x, -EFBIG, x->name, "a map of %llu x %llu is too large for the file",
				  (unsigned long long)dims[1], (unsigned long long)dims[0]);
	int r = lateral_spacing(x, "X Converter", &a->dx);
	if (r == 0)
		r = lateral_spacing(x, "Y Converter", &a->dy);
	if (r == 0)
		r = height_scale(x, &zs);
	if (r < 0)
		return r;
	_cleanup_free_ double *z = malloc(nodes * sizeof(double));
	if (!z)
		return asph_error_set(x->err, -ENOMEM, "out of memory");
	if (H5Dread(x->set, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, z) < 0)
		return datx_error(x, -EINVAL, x->name, "the map's values cannot be read");
	double nd_value = no_data(x);
	for (size_t k = 0; k < nodes; k++)
		z[k] = z[k] >= nd_value || !isfinite(z[k]) ? NAN : z[k] * zs;
	a->nx = (size_t)dims[1];
	a->ny = (size_t)dims[0];
	*out = steal_ptr(z);
	return 0;
}

/* The map of the file in data, decoded by libhdf5 (in the decoder's
 * process: decoder_run()). */
static int decode(const uint8_t *data, size_t len, const char *source, struct datx_answer *a,
		  double **z)
{
	struct datx x = { .source = source, .err = &a->err, .file = -1, .set = -1 };
	int r;

	/* HDF5 prints its error stack by default: the library stays quiet */
	H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
	hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
	if (fapl >= 0 && H5Pset_fapl_core(fapl, 1 << 20, 0) >= 0 &&
	    H5Pset_file_image(fapl, (void *)data, len) >= 0)
		/* the core driver refuses a name that exists as a file: one
		 * under /dev/null never does (nothing is opened by it) */
		x.file = H5Fopen("/dev/null/asph-datx-image", H5F_ACC_RDONLY, fapl);
	if (fapl >= 0)
		H5Pclose(fapl);
	if (x.file < 0)
		r = datx_error(&x, -EINVAL, NULL, "not a readable HDF5 file");
	else if ((r = open_map(&x)) == 0)
		r = read_map(&x, len, a, z);
	if (x.set >= 0)
		H5Dclose(x.set);
	if (x.file >= 0)
		H5Fclose(x.file);
	return r;
}

/*
 * libhdf5 is not safe with files it did not write: Debian 12's leaks on
 * malformed files and reads past a heap buffer (H5HG_read) on some of
 * them, and a reader of a file from anywhere must not take the program
 * down with it. So libhdf5 decodes the file in a process of its own,
 * forked for the one file, which sends the map back through a pipe and
 * ends with _exit() (what libhdf5 leaked or broke ends with it; nothing
 * of the caller's runs there: no atexit handlers, no flushing of the
 * caller's stdio). Its limits: address space for the image, the decoded
 * values and libhdf5's own work (DECODER_MEMORY), CPU time (RLIMIT_CPU,
 * DECODER_CPU_SECONDS) and, as a process that is stopped or waits would
 * use none, a wall-clock time of four times that. The caller only ever
 * sees the map, or an error naming the file and what happened. In a
 * program with threads the process holds only the forking one: glibc
 * keeps malloc usable there, and libhdf5 has never run in the caller's
 * process, so none of its locks can be held.
 */
#define DECODER_MEMORY(len) \
	(((size_t)512 << 20) + 2 * (len) + \
	 sizeof(double) * ((len) < POINTS_MAX / MAX_VALUES_PER_BYTE ? (len) * MAX_VALUES_PER_BYTE : POINTS_MAX))
#define DECODER_CPU_SECONDS(len) (20 + (len) / (8 << 20))

/* The address space the process maps now, bytes (0: unknown). */
static size_t address_space(void)
{
	unsigned long pages = 0;
	_cleanup_fclose_ FILE *f = fopen("/proc/self/statm", "re");

	if (!f || fscanf(f, "%lu", &pages) != 1)
		return 0;
	return pages * (size_t)sysconf(_SC_PAGESIZE);
}

static void decoder_limits(size_t len)
{
	rlim_t cpu = DECODER_CPU_SECONDS(len);
	struct rlimit l = { cpu, cpu + 1 }; /* SIGXCPU, then SIGKILL */
	size_t now = address_space();

	setrlimit(RLIMIT_CPU, &l);
	/* relative to what is mapped already: a sanitizer's shadow memory
	 * alone is terabytes. Unknown (no /proc): the CPU time bounds it. */
	if (now) {
		l.rlim_cur = l.rlim_max = now + DECODER_MEMORY(len);
		setrlimit(RLIMIT_AS, &l);
	}
}

/* The caller's signal handlers and mask are not for this process: a
 * handler of the caller's (a test framework's, a crash reporter's) could
 * take a crash of libhdf5 back into the caller's code here, and a blocked
 * SIGXCPU would not stop it. Every signal has its default action: a crash
 * ends the process, a reader gone away (SIGPIPE) too. */
static void reset_signals(void)
{
	sigset_t none;

	for (int sig = 1; sig < NSIG; sig++)
		signal(sig, SIG_DFL); /* SIGKILL, SIGSTOP and glibc's own refuse */
	sigemptyset(&none);
	sigprocmask(SIG_SETMASK, &none, NULL);
}

static _Noreturn void decoder_run(const uint8_t *data, size_t len, const char *source, int fd)
{
	struct datx_answer a;
	double *z = NULL;

	memset(&a, 0, sizeof(a)); /* every byte goes down the pipe */
	reset_signals();
	decoder_limits(len);
	a.code = decode(data, len, source, &a, &z);
	int r = fd_write_all(fd, &a, sizeof(a));
	if (r == 0 && a.code == 0)
		r = fd_write_all(fd, z, a.nx * a.ny * sizeof(double));
	free(z);
	_exit(r < 0 ? 1 : 0);
}

/* n bytes from fd into p before deadline (now_monotonic_ms()): 0,
 * -ETIMEDOUT, -EPIPE at an early end, or -errno. */
static int read_before(int fd, void *p, size_t n, uint64_t deadline)
{
	uint8_t *b = p;

	while (n > 0) {
		int64_t left = (int64_t)(deadline - now_monotonic_ms());
		struct pollfd pfd = { .fd = fd, .events = POLLIN };
		if (left <= 0)
			return -ETIMEDOUT;
		int k = poll(&pfd, 1, left > INT_MAX ? INT_MAX : (int)left);
		if (k < 0 && errno == EINTR)
			continue;
		if (k < 0)
			return -errno;
		if (k == 0)
			continue;
		ssize_t got = read(fd, b, n);
		if (got < 0 && errno == EINTR)
			continue;
		if (got < 0)
			return -errno;
		if (got == 0)
			return -EPIPE;
		b += got;
		n -= (size_t)got;
	}
	return 0;
}

/* The decoder's answer and its map (*z, malloc'd) before deadline. */
static int read_answer(int fd, struct datx_answer *a, double **z, uint64_t deadline)
{
	size_t nodes;
	int r = read_before(fd, a, sizeof(*a), deadline);

	if (r < 0 || a->code < 0)
		return r;
	if (points_map_size(a->nx, a->ny, sizeof(double), &nodes, NULL) < 0)
		return -EPROTO;
	*z = malloc(nodes * sizeof(double));
	if (!*z)
		return -ENOMEM;
	return read_before(fd, *z, nodes * sizeof(double), deadline);
}

/* Why the decoder gave no map: its end (wait status), or none in time. */
static int decoder_failed(const char *source, int status, int r, unsigned cpu,
			  struct asph_error *err)
{
	if (r == -ETIMEDOUT)
		return asph_error_set_at(err, -ETIMEDOUT, source, 0, 0, NULL,
					 "datx: libhdf5 gave no answer in %u s: the file was not read",
					 4 * cpu);
	if (WIFSIGNALED(status) && WTERMSIG(status) == SIGXCPU)
		return asph_error_set_at(err, -ETIME, source, 0, 0, NULL,
					 "datx: libhdf5 took over %u s of CPU time: the file was not read",
					 cpu);
	if (WIFSIGNALED(status))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "datx: libhdf5 crashed on the file (signal SIG%s): the file was not read",
					 sigabbrev_np(WTERMSIG(status)) ? sigabbrev_np(WTERMSIG(status)) : "?");
	if (r == -ENOMEM)
		return asph_error_set_at(err, -ENOMEM, source, 0, 0, NULL, "datx: out of memory");
	return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
				 "datx: libhdf5's decoding failed (exit status %d): the file was not read",
				 WIFEXITED(status) ? WEXITSTATUS(status) : -1);
}

int points_read_datx(const uint8_t *data, size_t len, const char *source,
		     struct asph_points **out, struct asph_points_read_info *info,
		     struct asph_error *err)
{
	unsigned cpu = DECODER_CPU_SECONDS(len);
	struct datx_answer a = { 0 };
	_cleanup_free_ double *z = NULL;
	int fds[2], status = 0;

	if (pipe2(fds, O_CLOEXEC) < 0)
		return asph_error_set_at(err, -errno, source, 0, 0, NULL,
					 "datx: no pipe for libhdf5's decoder: %s", strerror(errno));
	pid_t pid = fork();
	if (pid < 0) {
		int e = errno;
		close(fds[0]);
		close(fds[1]);
		return asph_error_set_at(err, -e, source, 0, 0, NULL,
					 "datx: no process for libhdf5's decoder: %s", strerror(e));
	}
	if (pid == 0) {
		close(fds[0]);
		decoder_run(data, len, source, fds[1]);
	}
	close(fds[1]);
	int r = read_answer(fds[0], &a, &z, now_monotonic_ms() + 4000 * (uint64_t)cpu);
	close(fds[0]);
	if (r == -ETIMEDOUT)
		kill(pid, SIGKILL);
	while (waitpid(pid, &status, 0) < 0 && errno == EINTR)
		;
	/* the decoder's own refusal of the file */
	if (r == 0 && a.code < 0) {
		if (err)
			*err = a.err;
		return a.code;
	}
	if (r < 0 || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
		return decoder_failed(source, status, r, cpu, err);
	struct points_map m = { .nx = a.nx, .ny = a.ny, .z = z };
	points_map_centre(&m, a.dx, a.dy, 1);
	return points_from_map(&m, "datx", source, out, info, err);
}
