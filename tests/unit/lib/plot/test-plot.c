/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "config.h"
#include "asph/plot.h"
#include "colormap.h"
#include "plot-layout.h"
#include "rmtree.h"

#if HAVE_CAIRO
#include <cairo.h>

struct image {
	cairo_surface_t *surface;
	int width, height, stride;
	const uint8_t *data;
};

static char tmpdir[64];

static int setup_dir(void **state)
{
	strcpy(tmpdir, "/tmp/test-plot-XXXXXX");
	return mkdtemp(tmpdir) ? 0 : -1;
}

static int remove_dir(void **state)
{
	return rmtree(tmpdir);
}

static void png_path(char *buf, size_t size, const char *name)
{
	snprintf(buf, size, "%s/%s", tmpdir, name);
}

static void load(const char *path, struct image *im)
{
	im->surface = cairo_image_surface_create_from_png(path);
	assert_int_equal(cairo_surface_status(im->surface), CAIRO_STATUS_SUCCESS);
	im->width = cairo_image_surface_get_width(im->surface);
	im->height = cairo_image_surface_get_height(im->surface);
	im->stride = cairo_image_surface_get_stride(im->surface);
	im->data = cairo_image_surface_get_data(im->surface);
}

static void pixel(const struct image *im, double u, double v, uint8_t rgb[3])
{
	int x = (int)floor(u), y = (int)floor(v);
	uint32_t p;

	assert_true(x >= 0 && x < im->width && y >= 0 && y < im->height);
	memcpy(&p, im->data + (size_t)y * (size_t)im->stride + 4 * (size_t)x, 4);
	rgb[0] = (uint8_t)(p >> 16);
	rgb[1] = (uint8_t)(p >> 8);
	rgb[2] = (uint8_t)p;
}

static void assert_colour(const uint8_t got[3], const uint8_t want[3], int tol)
{
	for (int k = 0; k < 3; k++)
		if (abs((int)got[k] - (int)want[k]) > tol)
			fail_msg("colour (%u,%u,%u), expected (%u,%u,%u)", got[0], got[1],
				 got[2], want[0], want[1], want[2]);
}

/* Fermat spiral: a near-hexagonal sampling of a disk, as plans are. */
static double *disk_points(size_t n, double cx, double cy, double radius)
{
	double *xyz = calloc(3 * n, sizeof(double));
	const double golden = M_PI * (3 - sqrt(5));

	assert_non_null(xyz);
	for (size_t i = 0; i < n; i++) {
		double r = radius * sqrt((i + 0.5) / (double)n), t = golden * (double)i;
		xyz[3 * i] = cx + r * cos(t);
		xyz[3 * i + 1] = cy + r * sin(t);
		xyz[3 * i + 2] = 0.01 * r * r;
	}
	return xyz;
}

static void single_frame(const double *xyz, size_t n, const uint32_t *tri,
			 size_t ntri, int w, int h, struct plot_frame *f)
{
	struct plot_rect panel;
	double ext[4];

	plot_data_extent(xyz, n, tri, ntri, ext);
	plot_figure_panel(w, h, 1, 0, &panel);
	plot_panel_frame(&panel, ext, f);
}

static void test_single_value_disk_is_uniform(void **state)
{
	const size_t n = 800;
	const double cx = 1.7, cy = -2.2, radius = 7.3;
	double *xyz = disk_points(n, cx, cy, radius);
	double *value = malloc(n * sizeof(double));
	struct asph_plot_options o = { .title = "uniform", .colour_label = "v",
				       .width = 640, .height = 520 };
	struct asph_error err;
	struct plot_frame f;
	struct image im;
	uint8_t got[3], want[3], white[3] = { 255, 255, 255 };
	char path[128];
	double u, v;

	for (size_t i = 0; i < n; i++)
		value[i] = 42.5;
	png_path(path, sizeof(path), "uniform.png");
	assert_int_equal(asph_plot_points_png(path, xyz, value, n, &o, &err), 0);
	load(path, &im);
	assert_int_equal(im.width, 640);
	assert_int_equal(im.height, 520);

	/* One value: the range is centred on it, so it is the middle colour. */
	colormap_sequential(0.5, want);
	single_frame(xyz, n, NULL, 0, 640, 520, &f);
	for (int i = -4; i <= 4; i++)
		for (int j = -4; j <= 4; j++) {
			double x = cx + 0.9 * radius * i / 4.0 * 0.7071;
			double y = cy + 0.9 * radius * j / 4.0 * 0.7071;
			plot_frame_to_pixel(&f, x, y, &u, &v);
			pixel(&im, u, v, got);
			assert_colour(got, want, 0);
		}
	/* The corners of the frame lie outside the disk: background. */
	plot_frame_to_pixel(&f, cx - 0.98 * radius, cy + 0.98 * radius, &u, &v);
	pixel(&im, u, v, got);
	assert_colour(got, white, 0);
	/* The colour bar runs from the bottom of the map to its top (a row
	 * may straddle two pixels: one unit of tolerance). */
	colormap_sequential(1 - 3.5 / f.bar.h, want);
	pixel(&im, f.bar.x + 0.5 * f.bar.w, f.bar.y + 3.5, got);
	assert_colour(got, want, 1);
	colormap_sequential(3.5 / f.bar.h, want);
	pixel(&im, f.bar.x + 0.5 * f.bar.w, f.bar.y + f.bar.h - 3.5, got);
	assert_colour(got, want, 1);
	cairo_surface_destroy(im.surface);
	free(xyz);
	free(value);
}

/* Quadrants with different values: x is not mirrored, y points up. */
static void test_quadrants_and_explicit_range(void **state)
{
	const size_t n = 1200;
	const double cx = -3.1, cy = 0.45, radius = 11.2;
	const double quad[4] = { -4.0, 1.5, 3.25, -0.75 }; /* ++, -+, --, +- */
	double *xyz = disk_points(n, cx, cy, radius);
	double *value = malloc(n * sizeof(double));
	struct asph_plot_options o = { .title = "quadrants", .colour_label = "residual (nm)",
				       .lo = -5, .hi = 5, .diverging = 1 };
	struct plot_frame f;
	struct image im;
	uint8_t got[3], want[3];
	char path[128];
	double u, v;

	for (size_t i = 0; i < n; i++) {
		int right = xyz[3 * i] > cx, up = xyz[3 * i + 1] > cy;
		value[i] = quad[right ? (up ? 0 : 3) : (up ? 1 : 2)];
	}
	png_path(path, sizeof(path), "quadrants.png");
	assert_int_equal(asph_plot_points_png(path, xyz, value, n, &o, NULL), 0);
	load(path, &im);
	assert_int_equal(im.width, 900);
	assert_int_equal(im.height, 760);
	single_frame(xyz, n, NULL, 0, 900, 760, &f);
	for (int q = 0; q < 4; q++) {
		double sx = (q == 0 || q == 3) ? 1 : -1, sy = q < 2 ? 1 : -1;
		plot_frame_to_pixel(&f, cx + 0.45 * radius * sx, cy + 0.45 * radius * sy, &u, &v);
		pixel(&im, u, v, got);
		colormap_diverging((quad[q] + 5) / 10, want);
		assert_colour(got, want, 0);
	}
	cairo_surface_destroy(im.surface);
	free(xyz);
	free(value);
}

static void test_triangles(void **state)
{
	const double xyz[] = { 0.3, -1.1, 0, 9.7, 0.4, 0.2, 2.9, 8.6, 0.1, -6.2, 5.3, 0.3 };
	const uint32_t tri[] = { 0, 1, 2, 0, 2, 3 };
	const double value[] = { 0.93, 2.71 };
	struct asph_plot_options o = { .title = "A_i / mean A", .colour_label = "A_i / mean A",
				       .lo = 0, .hi = 4, .width = 700, .height = 600 };
	struct plot_frame f;
	struct image im;
	uint8_t got[3], want[3], white[3] = { 255, 255, 255 };
	char path[128];
	double u, v;

	png_path(path, sizeof(path), "triangles.png");
	assert_int_equal(asph_plot_triangles_png(path, xyz, tri, 2, value, &o, NULL), 0);
	load(path, &im);
	single_frame(xyz, 4, tri, 2, 700, 600, &f);
	for (int t = 0; t < 2; t++) {
		double x = 0, y = 0;
		for (int k = 0; k < 3; k++) {
			x += xyz[3 * tri[3 * t + k]] / 3;
			y += xyz[3 * tri[3 * t + k] + 1] / 3;
		}
		plot_frame_to_pixel(&f, x, y, &u, &v);
		pixel(&im, u, v, got);
		colormap_sequential(value[t] / 4, want);
		assert_colour(got, want, 0);
	}
	/* Right of the long edge 1-2, inside the frame: nothing drawn. */
	plot_frame_to_pixel(&f, 9.0, 7.0, &u, &v);
	pixel(&im, u, v, got);
	assert_colour(got, white, 0);
	cairo_surface_destroy(im.surface);
}

static void test_two_panels(void **state)
{
	const size_t n = 500;
	double *xyz = disk_points(n, 0.2, 0.1, 4.4);
	double *z = malloc(n * sizeof(double));
	const uint32_t tri[] = { 0, 100, 300 };
	const double tv[] = { 0.77 };
	struct asph_plot_panel p[2] = {
		{ .kind = ASPH_PLOT_POINTS, .xyz = xyz, .n = n, .value = z,
		  .opts = { .title = "points", .colour_label = "z (mm)", .point_size = 0.4 } },
		{ .kind = ASPH_PLOT_TRIANGLES, .xyz = xyz, .n = n, .triangles = tri,
		  .n_triangles = 1, .value = tv,
		  .opts = { .title = "q", .colour_label = "q", .lo = 0, .hi = 1 } },
	};
	struct plot_rect panel;
	struct plot_frame f;
	struct image im;
	uint8_t got[3], want[3];
	char path[128];
	double ext[4], u, v, c[2] = { 0, 0 };

	for (size_t i = 0; i < n; i++)
		z[i] = xyz[3 * i + 2];
	png_path(path, sizeof(path), "panels.png");
	assert_int_equal(asph_plot_panels_png(path, p, 2, 0, 0, NULL), 0);
	load(path, &im);
	assert_int_equal(im.width, 1800);
	assert_int_equal(im.height, 760);
	plot_data_extent(xyz, n, tri, 1, ext);
	plot_figure_panel(1800, 760, 2, 1, &panel);
	plot_panel_frame(&panel, ext, &f);
	for (int k = 0; k < 3; k++) {
		c[0] += xyz[3 * tri[k]] / 3;
		c[1] += xyz[3 * tri[k] + 1] / 3;
	}
	plot_frame_to_pixel(&f, c[0], c[1], &u, &v);
	assert_true(u > 900);
	pixel(&im, u, v, got);
	colormap_sequential(0.77, want);
	assert_colour(got, want, 0);
	/* The outermost point of the left panel: the top of the z range. */
	plot_data_extent(xyz, n, NULL, 0, ext);
	plot_figure_panel(1800, 760, 2, 0, &panel);
	plot_panel_frame(&panel, ext, &f);
	plot_frame_to_pixel(&f, xyz[3 * (n - 1)], xyz[3 * (n - 1) + 1], &u, &v);
	pixel(&im, u, v, got);
	colormap_sequential(1, want);
	assert_colour(got, want, 0);
	cairo_surface_destroy(im.surface);
	free(xyz);
	free(z);
}

static void test_errors(void **state)
{
	const double xyz[] = { 0.5, 0.25, 0, 1.5, -0.5, 0, NAN, 2, 0 };
	const double value[] = { 1, 2, 3 };
	const uint32_t bad_tri[] = { 0, 1, 5 };
	struct asph_plot_options o = { .lo = 3, .hi = 1 };
	struct asph_plot_panel p = { .kind = ASPH_PLOT_TRIANGLES, .xyz = xyz, .n = 3,
				     .triangles = bad_tri, .n_triangles = 1 };
	struct asph_error err;
	char path[160];

	png_path(path, sizeof(path), "no/such/dir/x.png");
	assert_int_equal(asph_plot_points_png(path, xyz, value, 2, NULL, &err), -ENOENT);
	assert_non_null(strstr(err.message, "no/such/dir/x.png"));
	png_path(path, sizeof(path), "e.png");
	assert_int_equal(asph_plot_points_png(path, xyz, value, 0, NULL, &err), -EINVAL);
	assert_int_equal(asph_plot_points_png(path, xyz, value, 2, &o, &err), -EINVAL);
	assert_non_null(strstr(err.message, "colour range"));
	assert_int_equal(asph_plot_points_png(path, xyz, value, 3, NULL, &err), -EINVAL);
	assert_non_null(strstr(err.message, "point 2"));
	assert_int_equal(asph_plot_panels_png(path, &p, 1, 0, 0, &err), -EINVAL);
	assert_non_null(strstr(err.message, "triangle 0"));
	assert_int_equal(asph_plot_panels_png(path, &p, 0, 0, 0, &err), -EINVAL);
	o.lo = o.hi = 0;
	o.width = 50;
	assert_int_equal(asph_plot_points_png(path, xyz, value, 2, &o, &err), -EINVAL);
	assert_int_equal(access(path, F_OK), -1);
}

/* One point is a disc of 4 pixels' radius (plot_point_radius): its colour
 * in full inside, nothing 1 pixel beyond its rim, and its pixels' coverage
 * (how far each went from white to the colour) adds up to the disc's area,
 * pi r^2, within 1 %. */
static void test_disc_area(void **state)
{
	const double xyz[3] = { 3.25, -1.5, 0 }, value = 7;
	const double r = 4.0;
	struct asph_plot_options o = { .width = 400, .height = 360 };
	struct asph_error err;
	struct plot_frame f;
	struct image im;
	uint8_t got[3], want[3], white[3] = { 255, 255, 255 };
	char path[128];
	double u, v, area = 0;
	int k = 0;

	png_path(path, sizeof(path), "disc.png");
	assert_int_equal(asph_plot_points_png(path, xyz, &value, 1, &o, &err), 0);
	load(path, &im);
	colormap_sequential(0.5, want);
	single_frame(xyz, 1, NULL, 0, 400, 360, &f);
	plot_frame_to_pixel(&f, xyz[0], xyz[1], &u, &v);
	pixel(&im, u, v, got);
	assert_colour(got, want, 1);
	pixel(&im, u + r + 1.5, v, got);
	assert_colour(got, white, 0);
	pixel(&im, u, v - r - 1.5, got);
	assert_colour(got, white, 0);
	for (int c = 1; c < 3; c++)	/* the channel farthest from white */
		if (want[c] < want[k])
			k = c;
	for (int y = (int)floor(v - r - 2); y <= (int)ceil(v + r + 2); y++)
		for (int x = (int)floor(u - r - 2); x <= (int)ceil(u + r + 2); x++) {
			pixel(&im, x + 0.5, y + 0.5, got);
			area += (255.0 - got[k]) / (255.0 - want[k]);
		}
	cairo_surface_destroy(im.surface);
	assert_true(fabs(area - M_PI * r * r) < 0.01 * M_PI * r * r);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_single_value_disk_is_uniform),
		cmocka_unit_test(test_disc_area),
		cmocka_unit_test(test_quadrants_and_explicit_range),
		cmocka_unit_test(test_triangles),
		cmocka_unit_test(test_two_panels),
		cmocka_unit_test(test_errors),
	};

	int failed = cmocka_run_group_tests(tests, setup_dir, remove_dir);

	/* Drop cairo's font caches so that leak checkers see only our leaks. */
	cairo_debug_reset_static_data();
	return failed;
}

#else /* !HAVE_CAIRO */

static void test_not_supported(void **state)
{
	const double xyz[] = { 0.5, 0.25, 0 };
	const double value[] = { 1 };
	struct asph_error err;

	assert_int_equal(asph_plot_points_png("/tmp/x.png", xyz, value, 1, NULL, &err),
			 -ENOTSUP);
	assert_non_null(strstr(err.message, "cairo"));
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_not_supported),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}

#endif
