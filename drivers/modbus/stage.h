/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A Modbus stage: one drive per axis on one bus, driven through a register
 * map (a profile or the configuration): a direct data block that sets up
 * and starts a move, a command register with START, ZHOME, STOP and ALM-RST
 * bits, a status register with READY, BUSY, IN-POS, ALM and HOME-END, the
 * feedback position and the alarm code. Internal to drivers/modbus/.
 */
#ifndef ASPH_MODBUS_STAGE_H
#define ASPH_MODBUS_STAGE_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "asph-driver/driver.h"
#include "protocol.h"

struct stage_map {
	bool wide;                      /* 32-bit values (register pairs) */
	enum mb_word_order order;
	bool start_bit;                 /* START handshake, else the trigger */
	/* the data block: data number, operation type, position, speed,
	 * acceleration, deceleration, current, trigger; one value each */
	int reg_data;
	int reg_command, reg_status, reg_position, reg_alarm;
	int operation_type;
	int bit_start, bit_zhome, bit_stop, bit_alm_rst;
	int bit_ready, bit_busy, bit_in_pos, bit_alm, bit_home_end;
};

/* Indexed by the `profile` option's choices. */
extern const struct stage_map stage_profiles[];

struct stage_axis {
	int unit;
	double counts_per_unit;         /* counts per mm (rad for theta) */
	double speed, accel;            /* counts/s, counts/s^2 */
	int64_t target;                 /* counts, valid with moving */
	bool known;                     /* target is where the axis is */
};

struct stage {
	struct mb_bus *bus;
	atomic_bool *stop;
	struct stage_map map;
	struct stage_axis axes[3];
	struct asph_stage_info info;
	double current;                 /* % */
	int64_t window;                 /* in-position window, counts */
	unsigned poll_ms;
	bool reset_alarm;
	bool homed;
};

/* Refuses a setting whose value in drive units (counts) does not fit the
 * map's registers: -ERANGE naming the option and the register width. */
int stage_check_setting(const struct stage *s, const char *option, double value,
			const char *unit, double counts, struct asph_error *err);

/* Checks that every drive answers and releases its command bits. */
int stage_connect(struct stage *s, unsigned timeout_ms, struct asph_error *err);
int stage_home(struct stage *s, unsigned timeout_ms, struct asph_error *err);
int stage_move(struct stage *s, const double *target, unsigned timeout_ms,
	       struct asph_error *err);
int stage_position(struct stage *s, double *pos, unsigned timeout_ms,
		   struct asph_error *err);
int stage_status(struct stage *s, struct asph_stage_status *out,
		 unsigned timeout_ms, struct asph_error *err);

#endif
