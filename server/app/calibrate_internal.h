/*
 * calibrate_internal.h: the pieces of `terrad calibrate` (calibrate.c)
 * shared by its files — the measured data read from CSV and checked
 * (calibrate_data.c) and the plate fit. No tick runs here: calibrate is an
 * offline command that runs the bekker model's own single-wheel testbed
 * (sim_wheel_testbed) to fit a soil. Nothing outside server/app/ uses these.
 */
#ifndef TERRAD_CALIBRATE_INTERNAL_H
#define TERRAD_CALIBRATE_INTERNAL_H

#include "base/base.h"
#include "sim/sim.h"

/* One plate-sinkage point: a plate of least width b pressed to z under p. */
typedef struct cal_plate_row {
    int line; /* in its file, for messages */
    double width_m, pressure_pa, sinkage_m;
} cal_plate_row;

/* A measure the run may lack: has = 0 when the cell is empty. */
typedef struct cal_measure {
    int has;
    double value;
} cal_measure;

/* One single-wheel run at a slip (the wheel's size and load per row). */
typedef struct cal_wheel_row {
    int line;
    double radius_m, width_m, load_n, slip;
    collider_grousers grousers; /* zero: a smooth rim */
    cal_measure pull_n, sinkage_m, torque_nm;
} cal_wheel_row;

/* What the command line gives for the wheel columns a file may lack (0: none). */
typedef struct cal_wheel_defaults {
    double radius_m, width_m, load_n;
    collider_grousers grousers;             /* --grousers: for files without the columns */
    const char *where_column, *where_value; /* --where COL=VALUE, or NULL */
} cal_wheel_defaults;

/*
 * The plate file: columns width_m, pressure_pa, sinkage_m (others ignored),
 * '#' lines and blank lines skipped. Every value finite and > 0, at least two
 * widths with two rows each. Returns the row count, or -1 with err naming
 * the file, its line and the field. *rows is malloc'd.
 */
int cal_read_plates(const char *path, cal_plate_row **rows, error_text *err);
/*
 * The wheel file: slip and at least one of drawbar_pull_n, sinkage_m,
 * torque_nm; radius_m, width_m, load_n as columns or from d. Rows whose
 * where_column differs from where_value are skipped. At least two rows.
 */
int cal_read_wheel(const char *path, const cal_wheel_defaults *d, cal_wheel_row **rows,
                   error_text *err);

/* The plate fit's result and its residuals (one per row, in file order). */
typedef struct cal_plate_fit {
    double n, kc, kphi;
    int widths;
    int clamped;          /* 1: kc or kphi came out negative and was held at 0 */
    double *pressure_rel; /* (model - measured) / measured, per row */
    double *sinkage_rel;  /* the sinkage the fitted soil gives at the row's pressure, same */
} cal_plate_fit;

/*
 * Bekker's p = (kc/b + kphi) z^n by least squares in two linear steps (the
 * bevameter's own procedure, Wong, Theory of Ground Vehicles ch. 2): ln p
 * against ln z with one slope n for all widths and an intercept per width,
 * then k_b = kc (1/b) + kphi over the widths. Returns 0, or -1 with err when
 * the data cannot give a soil (all sinkages alike within a width, n out of
 * (0, 3]). fit->*_rel are malloc'd (cal_plate_fit_free).
 */
int cal_fit_plates(const cal_plate_row *rows, int count, const char *path, cal_plate_fit *fit,
                   error_text *err);
void cal_plate_fit_free(cal_plate_fit *fit);

#endif
