/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The characterization's state, shared by its pipeline, its JSON and its
 * writers. Internal. */
#ifndef ASPH_CHARACTERIZE_INTERNAL_H
#define ASPH_CHARACTERIZE_INTERNAL_H

#include <stdint.h>

#include "asph/characterize.h"

struct asph_characterization {
	const struct asph_surface *surface;
	struct asph_characterize_options opts;
	int done;                       /* characterized (once) */
	int from_scan;
	struct asph_points *points;
	struct asph_fit *fit;
	struct asph_scatter *scatter;
	struct asph_grid *grid;
	struct asph_psd *psd;
	double *map_xy, *map_nm;
	char *acquisition;
	/* run.data's SHA-256, hashed once when the characterization is made:
	 * the caller may then let the data's pages go (asphd's mapped scan)
	 * while the fit runs, and the writers need not touch them again. */
	char data_sha256[65];
	/* The descriptions of the scan's header (copies), or of the surface
	 * for points: what the report and result.json name. */
	char *prescription_json, *plan_json, *instrument_json, *metadata_json;
	/* how the plan was chosen, when the header's plan records it
	 * (asphd's plan for a tolerance: its "for_tolerance" member) */
	char *plan_choice_json;
	char *created;                  /* the scan's creation, ISO 8601 */
	int64_t created_ns, ended_ns;   /* its creation and its end block's */
	struct asph_characterize_result res;
};

/* The scan's descriptions (NULL for points without one). */
const char *characterize_instrument(const struct asph_characterization *c);
const char *characterize_plan(const struct asph_characterization *c);
/* Why the plan was chosen (result.json's plan_for_tolerance), or NULL. */
const char *characterize_plan_choice(const struct asph_characterization *c);
const char *characterize_metadata(const struct asph_characterization *c);
/* When the measurement was made and ended (ns since 1970), 0 when not
 * known. */
int64_t characterize_measured_ns(const struct asph_characterization *c);
int64_t characterize_measured_end_ns(const struct asph_characterization *c);
/* The job of the metadata, 0 when none. */
int64_t characterize_job(const struct asph_characterization *c);

/* The X3P grid's comment: "<kind> residual of <lens> after the best fit
 * (z in m)[, job N]". */
void characterize_x3p_comment(const struct asph_characterization *c, char *buf,
			      size_t size);

/* result.json's text (malloc'd) for the files listed in files (a json_t
 * object of key to file name); the hashes read from dir_fd. */
struct json_t;
int characterize_result_json(const struct asph_characterization *c,
			     const struct asph_characterize_folder *f, int dir_fd,
			     struct json_t *files, char **out, struct asph_error *err);

#endif
