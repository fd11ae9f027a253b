/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <math.h>

#include "colormap.h"

struct stop {
	double t;
	double r, g, b;
};

static void interpolate(const struct stop *stops, int n, double t,
			uint8_t rgb[3])
{
	if (isnan(t)) {
		rgb[0] = rgb[1] = rgb[2] = 128;
		return;
	}
	if (t <= stops[0].t)
		t = stops[0].t;
	if (t >= stops[n - 1].t)
		t = stops[n - 1].t;
	int i = 0;
	while (i < n - 2 && t > stops[i + 1].t)
		i++;
	double u = (t - stops[i].t) / (stops[i + 1].t - stops[i].t);
	double c[3] = {
		stops[i].r + u * (stops[i + 1].r - stops[i].r),
		stops[i].g + u * (stops[i + 1].g - stops[i].g),
		stops[i].b + u * (stops[i + 1].b - stops[i].b),
	};
	for (int k = 0; k < 3; k++)
		rgb[k] = (uint8_t)lround(255.0 * c[k]);
}

void colormap_diverging(double t, uint8_t rgb[3])
{
	static const struct stop stops[] = {
		{ 0.00, 0.230, 0.299, 0.754 },
		{ 0.25, 0.552, 0.690, 0.996 },
		{ 0.50, 0.950, 0.950, 0.950 },
		{ 0.75, 0.958, 0.603, 0.482 },
		{ 1.00, 0.706, 0.016, 0.150 },
	};
	interpolate(stops, 5, t, rgb);
}

void colormap_sequential(double t, uint8_t rgb[3])
{
	static const struct stop stops[] = {
		{ 0.00, 0.267, 0.005, 0.329 },
		{ 0.25, 0.229, 0.322, 0.546 },
		{ 0.50, 0.128, 0.567, 0.551 },
		{ 0.75, 0.369, 0.789, 0.383 },
		{ 1.00, 0.993, 0.906, 0.144 },
	};
	interpolate(stops, 5, t, rgb);
}
