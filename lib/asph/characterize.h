/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_CHARACTERIZE_H
#define ASPH_CHARACTERIZE_H

#include <stddef.h>
#include <stdint.h>

#include "asph/areal.h"
#include "asph/correction.h"
#include "asph/error.h"
#include "asph/fit.h"
#include "asph/points.h"
#include "asph/scanfile.h"
#include "asph/surface.h"
#include "asph/uncertainty.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Characterization, assembled once (docs/characterization.md): the points
 * of a recorded scan corrected for the drift its references measured (or
 * points as given), the best fit to the nominal surface with its form
 * quantities, slope, radius and verdict, the residual map of the part (its
 * interpolant, a grid, the radial PSD, band-limited RMS) and, through a
 * function of the caller's (libasph starts no threads), the Monte Carlo
 * uncertainty. asphd and asph (fit, replay, report) call it alike, and
 * every writer below takes its one result:
 *
 *	asph_characterize_alloc(surface, &opts, &c, &err);
 *	asph_characterize_scan(c, scan, name, &err);
 *	    (or asph_characterize_points(c, points, &err))
 *	asph_characterize_result(c), asph_characterize_summary_json(c, ...),
 *	asph_characterize_write_...(c, ...);
 *	asph_characterize_free(c);
 *
 * The characterization keeps what it needs of the scan (the points it
 * fits, the header's descriptions, the acquisition's account), not the
 * scan itself, which may be freed once asph_characterize_scan() returns.
 */

struct asph_characterization;

/*
 * Runs the Monte Carlo mc to its end and puts its statistics into out: on
 * threads of the caller's (asph_mc_run_threads()) or a block at a time
 * (asph_mc_next_block(), asph_mc_run_trials(), asph_mc_finish()). 0 or a
 * negative errno with err set; -ECANCELED when the caller stopped it.
 */
typedef int (*asph_characterize_mc_fn)(void *data, struct asph_mc *mc,
				       struct asph_mc_result *out,
				       struct asph_error *err);

/* What to compute besides the fit. */
enum asph_characterize_output {
	/* The residual map of the part: its interpolant (the X3P grid,
	 * the correction tables, the report and the PSD need it), the grid
	 * and the radial PSD. A scan too sparse for a map (too few points,
	 * all on a line) has none, and the fit stands. */
	ASPH_CHARACTERIZE_MAP = 1u << 0,
	/* Band-limited RMS of the grid (options' bands); implies the map. */
	ASPH_CHARACTERIZE_BANDS = 1u << 1,
};

/* The residual grid's nodes across the aperture's diameter, at most,
 * when its spacing is not given (8 MB of data). */
#define ASPH_CHARACTERIZE_GRID_NODES 1000

/*
 * What names the run in the files written (the X3P's Record2, the report,
 * result.json). The strings are the caller's and must outlive the
 * characterization. NULL (0) is "not given": then the recorded scan says,
 * where it does.
 */
struct asph_characterize_run {
	const char *program;        /* "asphd 0.1.0", "asph 0.1.0": the X3P's
				       Creator, the report's software */
	const char *lens_name;      /* NULL: the prescription's name */
	/* What was measured; NULL: the job's (the metadata's). */
	const char *part, *lot, *serial;
	/* Who measured; NULL: the job's submitter (the metadata's
	 * submitted_by.name), else default_operator. */
	const char *operator_name, *default_operator;
	/* The job (JSON object text: job, label, part, lot, serial,
	 * submitted_by, submitted, started_ns); NULL: the scan header's
	 * metadata. */
	const char *metadata_json;
	/* The recorded scan points come from (asph fit --scan), read only
	 * by asph_characterize_points(): its plan, instrument, metadata and
	 * times name the run as a characterized scan's do. */
	const struct asph_scanfile *source;
	/* When the measurement was made, ns since 1970; 0: the scan's
	 * creation and its end (unknown for points without a scan). */
	int64_t measured_ns;
	/* The measured data as read (the scan file, the points file), named
	 * and hashed in the report and result.json; NULL: not known. It is
	 * hashed once, by asph_characterize_alloc(): its bytes are not read
	 * after that. */
	const char *data_name;
	const void *data;
	size_t data_len;
};

struct asph_characterize_options {
	/* DOF, residual kind, robust, Zernike terms, wavelength, slope
	 * length and the tolerance (fit.tolerance, which must outlive the
	 * characterization; NULL: no verdict). */
	struct asph_fit_options fit;
	unsigned outputs;               /* enum asph_characterize_output */
	/* The grid's spacing; 0: the points' median spacing, no finer than
	 * the aperture's diameter / ASPH_CHARACTERIZE_GRID_NODES. */
	double grid_spacing_mm;
	struct asph_bands bands;        /* with ASPH_CHARACTERIZE_BANDS */
	/* The instrument's contributions; NULL (or all 0): no Monte Carlo,
	 * the uncertainties by covariance. The Monte Carlo runs only on a
	 * converged fit, with options mc (its seed 0 is seed 0), through
	 * run_mc, which is then required. */
	const struct asph_uncertainty_model *uncertainty;
	struct asph_mc_options mc;
	asph_characterize_mc_fn run_mc;
	void *run_mc_data;
	struct asph_characterize_run run;
};

/*
 * A characterization of points on the surface s (which must outlive it)
 * with opts (copied; what it points to must outlive it). -EINVAL for bad
 * options (err says which), -ENOMEM.
 */
int asph_characterize_alloc(const struct asph_surface *s,
			    const struct asph_characterize_options *opts,
			    struct asph_characterization **out,
			    struct asph_error *err);
void asph_characterize_free(struct asph_characterization *c);

/*
 * Characterizes the recorded scan (name locates errors): the points
 * asph_drift_scanfile_points() gives (the drift its references measured
 * corrected), the acquisition's account (asph_drift_report_json()), then
 * as asph_characterize_points(). The errors of the fit and of the Monte
 * Carlo; a fit that does not converge is not an error (the result says
 * so). Once per characterization.
 */
int asph_characterize_scan(struct asph_characterization *c,
			   const struct asph_scanfile *scan, const char *name,
			   struct asph_error *err);

/* As asph_characterize_scan(), but frees *scan (and sets it to NULL), also
 * on an error, once its points are taken and before the fit: a scan's
 * records take several times the memory of the points fitted, and the fit
 * and the map need none of them. */
int asph_characterize_scan_take(struct asph_characterization *c,
				struct asph_scanfile **scan, const char *name,
				struct asph_error *err);

/* Characterizes points (mm, machine frame, copied) as they are. */
int asph_characterize_points(struct asph_characterization *c,
			     const struct asph_points *points,
			     struct asph_error *err);

/* The result, after asph_characterize_scan() or _points(). */
struct asph_characterize_result {
	const struct asph_surface *surface;
	/* The points fitted, in scan order (the drift corrected). */
	const struct asph_points *points;
	/* The fit's workspace: the residual and status of each point
	 * (asph_fit_residuals(), asph_fit_point_status()). */
	const struct asph_fit *fit_workspace;
	/* The fit's result, with the Monte Carlo's expanded uncertainties
	 * and the verdict they decide when it ran. */
	struct asph_fit_result fit;
	int mc_done;
	struct asph_mc_result mc;
	/* The error asph_characterize_*() returned came from the Monte
	 * Carlo (else from reading the points or from the fit). */
	int uncertainty_failed;
	/* A scan's acquisition (JSON object text); NULL for points. */
	const char *acquisition_json;
	/* The map (ASPH_CHARACTERIZE_MAP): NULL when none was asked for or
	 * the points are too sparse for one (map_error says why). */
	const struct asph_scatter *scatter;
	const struct asph_grid *grid;
	double grid_spacing_mm;
	const struct asph_psd *psd;     /* NULL: too few samples */
	struct asph_error map_error;    /* code 0: no error */
	/* The used points as a map of the part (asph_fit_residual_map()),
	 * n_map of them, with the map. */
	const double *map_xy, *map_nm;
	size_t n_map;
	int bands_done;                 /* ASPH_CHARACTERIZE_BANDS */
	struct asph_band_rms bands;
	/* The scan characterized (0 and NULL for points). */
	size_t scan_points;
	unsigned scan_resumes;
	int scan_completed;             /* it ended with "completed" */
	const char *scan_outcome;       /* "completed", "unfinished", ... */
};

const struct asph_characterize_result *
asph_characterize_result(const struct asph_characterization *c);

/* The lens name the files give: the run's, else the prescription's. */
const char *asph_characterize_lens_name(const struct asph_characterization *c);

/* ------------------------------------------------------------- writers */

/*
 * The JSON summary (malloc'd text): the keys of asph_fit_result_to_json(),
 * then "acquisition" (a scan's), the Monte Carlo's keys (with it) and
 * "band_rms" (with bands): asphd's result "summary" and asph fit --json.
 * indent: 0 compact, else the spaces per level. 0, -EINVAL before the
 * characterization, -ENOMEM.
 */
int asph_characterize_summary_json(const struct asph_characterization *c, int indent,
				   char **out);

/* Which points the residual files hold. */
enum asph_characterize_points_set {
	ASPH_CHARACTERIZE_ALL_POINTS = 0,  /* every point, NaN where no foot
					      lies inside the aperture */
	ASPH_CHARACTERIZE_FITTED_POINTS,   /* the points used and the outliers */
	ASPH_CHARACTERIZE_USED_POINTS,     /* the points used */
};

/* The points of set with their residual in nm (value "residual_nm"). */
int asph_characterize_residual_points(const struct asph_characterization *c,
				      enum asph_characterize_points_set set,
				      struct asph_points **out, struct asph_error *err);

/*
 * The residual of each point of set: x, y, z and residual_nm as
 * asph_points_write() writes them (.csv, .ply coloured by the residual),
 * or, for .x3p, the list layout of x, y and the residual as Z (Record2
 * from the run).
 */
int asph_characterize_write_residuals(const struct asph_characterization *c,
				      const char *path,
				      enum asph_characterize_points_set set,
				      struct asph_error *err);

/* The residual of the points of set seen from +z, a colour bar in nm. */
int asph_characterize_write_map(const struct asph_characterization *c, const char *path,
				const char *title, enum asph_characterize_points_set set,
				struct asph_error *err);

/* The residual grid (ISO 25178-72 matrix layout); the map's error when
 * there is none. */
int asph_characterize_write_x3p(const struct asph_characterization *c, const char *path,
				struct asph_error *err);

/* The radial PSD as CSV, f_per_mm,psd_nm2_mm; -EDOM when there is none. */
int asph_characterize_write_psd(const struct asph_characterization *c, const char *path,
				struct asph_error *err);

/* A correction table of the residual (asph/correction.h). */
int asph_characterize_write_correction(const struct asph_characterization *c,
				       const char *path,
				       const struct asph_correction_options *opts,
				       struct asph_error *err);

/* The measurement report (asph/report.h); -ENOTSUP without cairo. */
int asph_characterize_write_report(const struct asph_characterization *c,
				   const char *path, struct asph_error *err);

/* What result.json says besides the characterization. */
struct asph_characterize_folder {
	unsigned mode;                  /* of the files (the umask applies) */
	const char *scan_file;          /* the scan's name in the folder */
	/* provenance.software: a JSON object text ({"asphd": "0.1.0", ...}) */
	const char *software_json;
	/* provenance.fit_options (JSON object text); NULL: the options' */
	const char *fit_options_json;
	const char *tolerance_json;     /* provenance.tolerance; NULL: none */
	int64_t finished_ns;            /* provenance.finished; 0: now */
};

/*
 * The result files of a scan's characterization, as asphd writes them
 * into a job's folder (docs/daemon.md): residuals.csv (every point),
 * residual-map.png (with cairo), residual.x3p and psd.csv (with a map),
 * report.pdf (with cairo and a map), and result.json (job, summary,
 * provenance, hashes, files, and plan_for_tolerance when the scan's
 * header plan records how it was chosen: its "for_tolerance" member,
 * which provenance.plan leaves out), each created exclusively under a temporary
 * name in dir_fd and renamed into place. *result_json (may be NULL)
 * receives result.json's text. Needs a characterized scan, or points with
 * their data (run.data): then f->scan_file names the measured file, listed
 * as files.measured and provenance.measured, with no plan (-EINVAL).
 */
int asph_characterize_write_folder(const struct asph_characterization *c, int dir_fd,
				   const struct asph_characterize_folder *f,
				   char **result_json, struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
