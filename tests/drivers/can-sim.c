/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Simulated CANopen CiA 402 drives on a descriptor (see can-sim.h). */
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <linux/can/error.h>

#include "can-sim.h"
#include "util-time.h"

#define ABORT_NO_OBJECT 0x06020000u
#define ABORT_NO_SUBINDEX 0x06090011u
#define ABORT_READ_ONLY 0x06010002u
#define ABORT_LENGTH 0x06070010u
#define ABORT_LENGTH_HIGH 0x06070012u
#define ABORT_LENGTH_LOW 0x06070013u
#define ABORT_VALUE 0x06090030u
#define ABORT_TOO_LOW 0x06090032u
#define ABORT_COMMAND 0x05040001u
#define ABORT_STATE 0x08000022u

struct sim_node {
	uint8_t id;
	uint32_t device_type;
	uint8_t nmt;
	bool silent, heartbeat_on, homing_error, fault_persistent;
	uint16_t hb_ms;
	uint64_t next_hb_ns;
	/* CiA 402 */
	enum cia402_state state;
	uint16_t cw, error_code;
	int8_t mode, method;
	double pos;             /* counts */
	int32_t target;
	uint32_t velocity, accel, decel, homing_speed[2], homing_accel;
	bool ack, reached, moving, homing, attained, homing_failed;
	double goal;            /* where the motion goes */
	bool buffered;          /* a set point waits behind the one in process */
	double buffered_goal;
	unsigned buffered_set_points;
	uint64_t first_set_point_ns;    /* the first set point taken in profile position */
	unsigned sdo_requests;          /* SDO requests it answered */
	/* touch probe 1 and the digital outputs */
	uint8_t tp_kind;        /* enum can_sim_touch_probe */
	uint16_t tp_function, tp_status;
	int32_t tp_positive, tp_negative;
	uint16_t tp_positive_count, tp_negative_count;
	bool tp_armed_positive, tp_armed_negative;
	uint32_t outputs, output_mask;
	uint16_t fault_on_move;
	uint64_t fault_at_ns;
	int16_t probe;
	/* injections */
	uint16_t abort_index;
	uint8_t abort_sub;
	uint32_t abort_code;
	enum can_sim_garble garble;
	/* counters */
	unsigned quick_stops, fault_resets, set_points, homings, resets, disable_ops, link_stops;
	bool homed;
};

struct can_sim {
	int fd, wake;
	struct can_sim_config cfg;
	pthread_mutex_t lock;
	pthread_t thread;
	bool running;
	atomic_bool quit;
	uint64_t last_tick_ns;
	struct sim_node nodes[CAN_SIM_MAX_NODES];
	struct can_frame pending[8];    /* error frames to send */
	unsigned n_pending;
	/* the trigger line: driven from outside or by a drive's output */
	bool line_external, line_output, line;
	bool bounce;            /* each rise of the output bounces once */
	struct can_sim_edge *edges;
	size_t n_edges;
};

#define MAX_EDGES 8192

static struct sim_node *find(struct can_sim *s, uint8_t id)
{
	for (unsigned i = 0; i < s->cfg.n_nodes; i++)
		if (s->nodes[i].id == id)
			return &s->nodes[i];
	return NULL;
}

/* Answers wait for room (the client drains while it waits); heartbeats
 * are dropped when the client does not read, as a full CAN queue does. */
static void send_bytes(struct can_sim *s, const void *buf, size_t len, bool answer)
{
	struct pollfd p = { s->fd, POLLOUT, 0 };

	if (answer && poll(&p, 1, 500) <= 0)
		return;
	ssize_t w = send(s->fd, buf, len, MSG_DONTWAIT | MSG_NOSIGNAL);
	(void)w;
}

static void send_frame(struct can_sim *s, const struct can_frame *f, bool answer)
{
	send_bytes(s, f, sizeof(*f), answer);
}

static void enter_fault(struct can_sim *s, struct sim_node *n, uint16_t code)
{
	struct can_frame f;

	n->state = CIA402_FAULT;
	n->error_code = code;
	n->moving = n->homing = false;
	n->reached = true;
	canopen_emcy_frame(&f, n->id, code, 0x01);
	send_frame(s, &f, false);
}

static void reset_node(struct can_sim *s, struct sim_node *n, bool application)
{
	struct can_frame f;

	n->nmt = CANOPEN_STATE_PRE_OPERATIONAL;
	n->hb_ms = (uint16_t)s->cfg.heartbeat_ms;
	n->next_hb_ns = now_monotonic_ns() + n->hb_ms * 1000000ull;
	n->resets++;
	if (application) {
		n->state = CIA402_SWITCH_ON_DISABLED;
		n->cw = 0;
		n->mode = 0;
		n->error_code = 0;
		n->moving = n->homing = n->ack = n->buffered = false;
		n->homed = n->attained = false;
		n->tp_function = n->tp_status = 0;
		n->tp_armed_positive = n->tp_armed_negative = false;
		n->outputs = n->output_mask = 0;
	}
	canopen_heartbeat_frame(&f, n->id, CANOPEN_STATE_BOOTUP);
	send_frame(s, &f, true);
}

/* ------------------------------------------------------------ motion */

static void start_homing(struct sim_node *n)
{
	n->homings++;
	n->attained = n->homing_failed = false;
	n->reached = false;
	if (n->homing_error) {
		n->homing_failed = true;
		n->reached = true;
		return;
	}
	n->homing = true;
}

static void finish_homing(struct sim_node *n)
{
	/* the home position becomes 0 */
	n->pos = 0;
	n->target = 0;
	n->homing = false;
	n->attained = n->reached = n->homed = true;
}

static void controlword(struct can_sim *s, struct sim_node *n, uint16_t cw)
{
	uint16_t prev = n->cw;
	enum cia402_state was = n->state;

	n->cw = cw;
	if ((cw & 0x06) == 0x02)
		n->quick_stops++;
	if ((cw & 0x0f) == 0x07 && was == CIA402_OPERATION_ENABLED)
		n->disable_ops++;
	if (n->state == CIA402_FAULT && (cw & 0x80) && !(prev & 0x80)) {
		n->fault_resets++;
		if (!n->fault_persistent) {
			struct can_frame f;
			n->error_code = 0;
			canopen_emcy_frame(&f, n->id, 0, 0);
			send_frame(s, &f, false);
		}
	}
	n->state = cia402_next_state(n->state, prev, cw, !n->fault_persistent);
	if (n->state != CIA402_OPERATION_ENABLED) {
		n->moving = n->homing = n->buffered = false;
		n->reached = true;
		if (was == CIA402_OPERATION_ENABLED)
			n->ack = false;
		return;
	}
	bool rise = (cw & 0x10) && !(prev & 0x10), fall = !(cw & 0x10) && (prev & 0x10);
	if (n->mode == CIA402_MODE_PROFILE_POSITION) {
		/* bit 12 stays up while a set point waits in the buffer: the
		 * drive cannot take another one */
		if (fall && !n->buffered)
			n->ack = false;
		if (rise && !n->ack) {
			n->ack = true;
			n->set_points++;
			if (!n->first_set_point_ns)
				n->first_set_point_ns = now_monotonic_ns();
			if (n->moving && !(cw & CIA402_CW_CHANGE_IMMEDIATELY)) {
				/* after the one in process (relative: to its target) */
				n->buffered = true;
				n->buffered_set_points++;
				n->buffered_goal = (cw & 0x40) ? n->goal + n->target : n->target;
				return;
			}
			n->goal = (cw & 0x40) ? n->pos + n->target : n->target;
			n->reached = false;
			n->moving = true;
			if (n->fault_on_move)
				n->fault_at_ns = now_monotonic_ns() + 3000000;
		}
	} else if (n->mode == CIA402_MODE_HOMING) {
		if (rise)
			start_homing(n);
		if (fall && n->homing)
			n->homing = false;
	}
}

static void step(struct can_sim *s, struct sim_node *n, double dt, uint64_t now)
{
	if (n->fault_at_ns && now >= n->fault_at_ns) {
		n->fault_at_ns = 0;
		enter_fault(s, n, n->fault_on_move);
		n->fault_on_move = 0;
		return;
	}
	if (n->moving || n->homing) {
		int k = (int)(n - s->nodes);
		double goal = n->moving ? n->goal : s->cfg.home_switch[k];
		double v = (n->moving ? n->velocity : n->homing_speed[0]) * s->cfg.speed_factor;
		bool instant = s->cfg.speed_factor == 0 ||
			       (n->homing && (n->method == 35 || n->method == 37));
		double d = goal - n->pos, stepv = v * dt;
		if (n->homing) {
			if (instant || fabs(d) <= stepv)
				finish_homing(n);
			else
				n->pos += d > 0 ? stepv : -stepv;
			return;
		}
		/* through a buffered set point's target at the same speed (no
		 * acceleration is simulated, so bit 9 changes nothing here) */
		for (;;) {
			d = n->goal - n->pos;
			if (!instant && fabs(d) > stepv) {
				n->pos += d > 0 ? stepv : -stepv;
				return;
			}
			stepv -= fabs(d);
			n->pos = n->goal;
			if (!n->buffered) {
				n->moving = false;
				n->reached = true;
				return;
			}
			n->goal = n->buffered_goal;
			n->buffered = false;
			if (!(n->cw & CIA402_CW_NEW_SET_POINT))
				n->ack = false;
		}
	}
}

/* ------------------------------------------------------ touch probe */

/* An edge of the trigger line: each drive whose touch probe is armed for
 * it latches its encoder as it is at this instant. */
static void trigger_edge(struct can_sim *s, bool rising)
{
	uint64_t now = now_monotonic_ns();

	if (s->n_edges++ < MAX_EDGES) {
		struct can_sim_edge *e = &s->edges[s->n_edges - 1];
		e->t_ns = now;
		e->rising = rising;
		for (unsigned i = 0; i < s->cfg.n_nodes; i++) {
			e->encoder[i] = (int32_t)lround(s->nodes[i].pos);
			e->goal[i] = (int32_t)lround(s->nodes[i].goal);
		}
	}
	for (unsigned i = 0; i < s->cfg.n_nodes; i++) {
		struct sim_node *n = &s->nodes[i];
		uint16_t f = n->tp_function;
		if (n->tp_kind == CAN_SIM_TP_NONE || !(f & CIA402_TP_ENABLE))
			continue;
		bool continuous = f & CIA402_TP_CONTINUOUS;
		int32_t at = (int32_t)lround(n->pos);
		if (rising && (f & CIA402_TP_POSITIVE_EDGE) && n->tp_armed_positive) {
			n->tp_positive = at;
			n->tp_status |= CIA402_TPS_POSITIVE_STORED;
			n->tp_positive_count++;
			n->tp_armed_positive = continuous;
		}
		if (!rising && (f & CIA402_TP_NEGATIVE_EDGE) && n->tp_armed_negative) {
			n->tp_negative = at;
			n->tp_status |= CIA402_TPS_NEGATIVE_STORED;
			n->tp_negative_count++;
			n->tp_armed_negative = continuous;
		}
	}
}

static void update_line(struct can_sim *s)
{
	bool level = s->line_external || s->line_output;

	if (level != s->line) {
		s->line = level;
		trigger_edge(s, level);
		if (level && s->bounce && s->line_output && !s->line_external) {
			trigger_edge(s, false);
			trigger_edge(s, true);
		}
	}
}

static void set_outputs(struct can_sim *s, struct sim_node *n)
{
	if (!s->cfg.trigger_node || n->id != s->cfg.trigger_node)
		return;
	uint32_t bit = 1u << s->cfg.trigger_bit;
	s->line_output = (n->outputs & n->output_mask & bit) != 0;
	update_line(s);
}

/*
 * A write of 0x60B8. Refused: bits the drive does not have (touch probe
 * 2, the user-defined bits 6-7), a source other than the touch probe 1
 * input (the simulated encoder has no zero impulse, 0x60D0 does not
 * exist, 11 is reserved), and a change of mode or source while the probe
 * stays switched on (it must be switched off first). Arming: a rising edge
 * of bit 4 (or 5), or of bit 0 with it set, arms the latch and clears the
 * stored flag; in first-event mode one edge disarms it again.
 */
static uint32_t touch_probe_function(struct sim_node *n, uint16_t f)
{
	uint16_t old = n->tp_function;

	if (f & 0xffc0)
		return ABORT_VALUE;
	if (f & CIA402_TP_SOURCE_MASK)
		return ABORT_VALUE;
	if ((old & CIA402_TP_ENABLE) && (f & CIA402_TP_ENABLE) &&
	    ((old ^ f) & (CIA402_TP_CONTINUOUS | CIA402_TP_SOURCE_MASK)))
		return ABORT_STATE;
	n->tp_function = f;
	if (!(f & CIA402_TP_ENABLE)) {
		n->tp_status = 0;
		n->tp_armed_positive = n->tp_armed_negative = false;
		return 0;
	}
	n->tp_status |= CIA402_TPS_ENABLED;
	bool was_on = old & CIA402_TP_ENABLE;
	if (!(f & CIA402_TP_POSITIVE_EDGE)) {
		n->tp_armed_positive = false;
		n->tp_status &= (uint16_t)~CIA402_TPS_POSITIVE_STORED;
	} else if (!was_on || !(old & CIA402_TP_POSITIVE_EDGE)) {
		n->tp_armed_positive = true;
		n->tp_status &= (uint16_t)~CIA402_TPS_POSITIVE_STORED;
	}
	if (!(f & CIA402_TP_NEGATIVE_EDGE)) {
		n->tp_armed_negative = false;
		n->tp_status &= (uint16_t)~CIA402_TPS_NEGATIVE_STORED;
	} else if (!was_on || !(old & CIA402_TP_NEGATIVE_EDGE)) {
		n->tp_armed_negative = true;
		n->tp_status &= (uint16_t)~CIA402_TPS_NEGATIVE_STORED;
	}
	return 0;
}

static bool tp_object(uint16_t index)
{
	return index == CIA402_TOUCH_PROBE_FUNCTION || index == CIA402_TOUCH_PROBE_STATUS ||
	       index == CIA402_TOUCH_PROBE1_POSITIVE || index == CIA402_TOUCH_PROBE1_NEGATIVE ||
	       index == CIA402_TOUCH_PROBE1_POS_COUNT || index == CIA402_TOUCH_PROBE1_NEG_COUNT;
}

/* The touch probe objects and 0x60FE: 0 with the value, or an abort code. */
static uint32_t od_read_io(struct sim_node *n, uint16_t index, uint8_t sub, uint32_t *v,
			   uint8_t *size)
{
	if (index == CIA402_DIGITAL_OUTPUTS) {
		if (sub > 2)
			return ABORT_NO_SUBINDEX;
		*size = sub ? 4 : 1;
		*v = sub == 0 ? 2 : sub == 1 ? n->outputs : n->output_mask;
		return 0;
	}
	if (n->tp_kind == CAN_SIM_TP_NONE ||
	    (n->tp_kind == CAN_SIM_TP_NO_COUNTER && (index == CIA402_TOUCH_PROBE1_POS_COUNT ||
						     index == CIA402_TOUCH_PROBE1_NEG_COUNT)))
		return ABORT_NO_OBJECT;
	if (sub != 0)
		return ABORT_NO_SUBINDEX;
	*size = 2;
	switch (index) {
	case CIA402_TOUCH_PROBE_FUNCTION: *v = n->tp_function; break;
	case CIA402_TOUCH_PROBE_STATUS: *v = n->tp_status; break;
	case CIA402_TOUCH_PROBE1_POSITIVE: *v = (uint32_t)n->tp_positive; *size = 4; break;
	case CIA402_TOUCH_PROBE1_NEGATIVE: *v = (uint32_t)n->tp_negative; *size = 4; break;
	case CIA402_TOUCH_PROBE1_POS_COUNT: *v = n->tp_positive_count; break;
	default: *v = n->tp_negative_count; break;
	}
	return 0;
}

static void tick(struct can_sim *s)
{
	uint64_t now = now_monotonic_ns();
	double dt = s->last_tick_ns ? (double)(now - s->last_tick_ns) * 1e-9 : 0;
	struct can_frame f;

	s->last_tick_ns = now;
	for (unsigned i = 0; i < s->cfg.n_nodes; i++) {
		struct sim_node *n = &s->nodes[i];
		step(s, n, dt, now);
		if (!n->silent && n->heartbeat_on && n->hb_ms && now >= n->next_hb_ns) {
			n->next_hb_ns = now + n->hb_ms * 1000000ull;
			canopen_heartbeat_frame(&f, n->id, n->nmt);
			send_frame(s, &f, false);
		}
	}
}

/* -------------------------------------------------------------- SDO */

static uint16_t statusword(const struct sim_node *n)
{
	uint16_t sw = cia402_statusword_bits(n->state) | 0x0200;  /* remote */

	if (n->reached)
		sw |= CIA402_SW_TARGET_REACHED;
	if (n->mode == CIA402_MODE_PROFILE_POSITION && n->ack)
		sw |= CIA402_SW_BIT12;
	if (n->mode == CIA402_MODE_HOMING) {
		if (n->attained)
			sw |= CIA402_SW_BIT12;
		if (n->homing_failed)
			sw |= CIA402_SW_BIT13;
	}
	return sw;
}

/* The object dictionary: 0 with the value and its size, or an abort code. */
static uint32_t od_read(struct sim_node *n, uint16_t index, uint8_t sub, uint32_t *v, uint8_t *size)
{
	*size = 4;
	if (tp_object(index) || index == CIA402_DIGITAL_OUTPUTS)
		return od_read_io(n, index, sub, v, size);
	if (index == CIA402_HOMING_SPEEDS) {
		if (sub > 2)
			return ABORT_NO_SUBINDEX;
		*size = sub ? 4 : 1;
		*v = sub ? n->homing_speed[sub - 1] : 2;
		return 0;
	}
	if (index == 0x7130) {
		if (sub > 1)
			return ABORT_NO_SUBINDEX;
		*size = sub ? 2 : 1;
		*v = 1;
		if (!sub)
			return 0;
		*v = (uint16_t)n->probe;
		return 0;
	}
	if (sub != 0)
		return ABORT_NO_SUBINDEX;
	switch (index) {
	case CANOPEN_DEVICE_TYPE: *v = n->device_type; break;
	case CANOPEN_HEARTBEAT_TIME: *v = n->hb_ms; *size = 2; break;
	case CIA402_ERROR_CODE: *v = n->error_code; *size = 2; break;
	case CIA402_CONTROLWORD: *v = n->cw; *size = 2; break;
	case CIA402_STATUSWORD: *v = statusword(n); *size = 2; break;
	case CIA402_MODE: *v = (uint8_t)n->mode; *size = 1; break;
	case CIA402_MODE_DISPLAY: *v = (uint8_t)n->mode; *size = 1; break;
	case CIA402_POSITION_ACTUAL: *v = (uint32_t)(int32_t)lround(n->pos); break;
	case CIA402_TARGET_POSITION: *v = (uint32_t)n->target; break;
	case CIA402_PROFILE_VELOCITY: *v = n->velocity; break;
	case CIA402_PROFILE_ACCELERATION: *v = n->accel; break;
	case CIA402_PROFILE_DECELERATION: *v = n->decel; break;
	case CIA402_HOMING_METHOD: *v = (uint8_t)n->method; *size = 1; break;
	case CIA402_HOMING_ACCELERATION: *v = n->homing_accel; break;
	default: return ABORT_NO_OBJECT;
	}
	return 0;
}

static bool method_supported(int8_t m)
{
	return m == 1 || m == 2 || m == 17 || m == 18 || m == 35 || m == 37;
}

static uint32_t od_write(struct can_sim *s, struct sim_node *n, uint16_t index, uint8_t sub,
			 uint32_t v, uint8_t size)
{
	uint32_t old;
	uint8_t want;
	uint32_t r = od_read(n, index, sub, &old, &want);

	if (r)
		return r;
	switch (index) {
	case CANOPEN_DEVICE_TYPE: case CIA402_STATUSWORD: case CIA402_MODE_DISPLAY:
	case CIA402_POSITION_ACTUAL: case CIA402_ERROR_CODE: case 0x7130:
	case CIA402_TOUCH_PROBE_STATUS: case CIA402_TOUCH_PROBE1_POSITIVE:
	case CIA402_TOUCH_PROBE1_NEGATIVE: case CIA402_TOUCH_PROBE1_POS_COUNT:
	case CIA402_TOUCH_PROBE1_NEG_COUNT:
		return ABORT_READ_ONLY;
	default:
		break;
	}
	if ((index == CIA402_HOMING_SPEEDS || index == CIA402_DIGITAL_OUTPUTS) && sub == 0)
		return ABORT_READ_ONLY;
	if (size && size != want)
		return size > want ? ABORT_LENGTH_HIGH : ABORT_LENGTH_LOW;
	switch (index) {
	case CANOPEN_HEARTBEAT_TIME: n->hb_ms = (uint16_t)v; break;
	case CIA402_CONTROLWORD: controlword(s, n, (uint16_t)v); break;
	case CIA402_MODE:
		if ((int8_t)v != CIA402_MODE_PROFILE_POSITION && (int8_t)v != CIA402_MODE_HOMING)
			return ABORT_VALUE;
		if (n->moving || n->homing)
			return ABORT_STATE;
		n->mode = (int8_t)v;
		break;
	case CIA402_TARGET_POSITION: n->target = (int32_t)v; break;
	case CIA402_PROFILE_VELOCITY:
		if (!v)
			return ABORT_TOO_LOW;
		n->velocity = v;
		break;
	case CIA402_PROFILE_ACCELERATION: n->accel = v; break;
	case CIA402_PROFILE_DECELERATION: n->decel = v; break;
	case CIA402_HOMING_METHOD:
		if (!method_supported((int8_t)v))
			return ABORT_VALUE;
		n->method = (int8_t)v;
		break;
	case CIA402_HOMING_SPEEDS: n->homing_speed[sub - 1] = v; break;
	case CIA402_HOMING_ACCELERATION: n->homing_accel = v; break;
	case CIA402_TOUCH_PROBE_FUNCTION: return touch_probe_function(n, (uint16_t)v);
	case CIA402_DIGITAL_OUTPUTS:
		/* bit 0 is the brake, bits 1..15 are reserved */
		if (sub == 1 && (v & 0xfffe))
			return ABORT_VALUE;
		if (sub == 1)
			n->outputs = v;
		else
			n->output_mask = v;
		set_outputs(s, n);
		break;
	default: return ABORT_LENGTH;
	}
	return 0;
}

static void answer(struct can_sim *s, struct sim_node *n, const struct canopen_sdo *q)
{
	struct can_frame f;
	uint32_t v = 0, code;
	uint8_t size = 0;

	if (q->kind == SDO_ABORT)
		return;
	if (n->abort_code && q->index == n->abort_index && q->subindex == n->abort_sub)
		code = n->abort_code;
	else if (q->kind == SDO_UPLOAD)
		code = od_read(n, q->index, q->subindex, &v, &size);
	else if (q->kind == SDO_DOWNLOAD)
		code = od_write(s, n, q->index, q->subindex, q->value, q->size);
	else
		code = ABORT_COMMAND;
	if (code)
		canopen_sdo_abort_frame(&f, n->id, false, q->index, q->subindex, code);
	else
		canopen_sdo_frame(&f, n->id, false, q->kind, q->index, q->subindex, v, size);
	unsigned char longer[sizeof(f) + 8];
	enum can_sim_garble g = n->garble;

	n->garble = CAN_SIM_GARBLE_NONE;
	switch (g) {
	case CAN_SIM_SHORT: f.can_dlc = 5; break;
	case CAN_SIM_SEGMENTED: f.data[0] = 0x41; break;       /* a segmented upload follows */
	case CAN_SIM_OTHER_INDEX: f.data[1] ^= 0x01; break;
	case CAN_SIM_LONG:
		memcpy(longer, &f, sizeof(f));
		memset(longer + sizeof(f), 0x5a, sizeof(longer) - sizeof(f));
		send_bytes(s, longer, sizeof(longer), true);
		return;
	default: break;
	}
	send_frame(s, &f, true);
}

static void nmt(struct can_sim *s, struct sim_node *n, uint8_t command)
{
	switch (command) {
	case CANOPEN_NMT_START: n->nmt = CANOPEN_STATE_OPERATIONAL; break;
	case CANOPEN_NMT_STOP: n->nmt = CANOPEN_STATE_STOPPED; break;
	case CANOPEN_NMT_PRE_OPERATIONAL: n->nmt = CANOPEN_STATE_PRE_OPERATIONAL; break;
	case CANOPEN_NMT_RESET_NODE: reset_node(s, n, true); break;
	case CANOPEN_NMT_RESET_COMMUNICATION: reset_node(s, n, false); break;
	default: break;
	}
}

void can_sim_feed(struct can_sim *s, const struct can_frame *f)
{
	struct can_event ev;

	if (canopen_decode(f, &ev) < 0)
		return;         /* a real node ignores what it cannot parse */
	pthread_mutex_lock(&s->lock);
	tick(s);
	for (unsigned i = 0; i < s->cfg.n_nodes; i++) {
		struct sim_node *n = &s->nodes[i];
		if (n->silent)
			continue;
		if (ev.type == CAN_EV_NMT && (ev.u.nmt.node == 0 || ev.u.nmt.node == n->id))
			nmt(s, n, ev.u.nmt.command);
		/* SDO is served in pre-operational and operational only */
		if (ev.type == CAN_EV_SDO_REQUEST && ev.node == n->id &&
		    n->nmt != CANOPEN_STATE_STOPPED) {
			n->sdo_requests++;
			answer(s, n, &ev.u.sdo);
		}
	}
	pthread_mutex_unlock(&s->lock);
}

/* ----------------------------------------------------------- thread */

static bool busy(const struct can_sim *s)
{
	for (unsigned i = 0; i < s->cfg.n_nodes; i++)
		if (s->nodes[i].moving || s->nodes[i].homing || s->nodes[i].fault_at_ns)
			return true;
	return false;
}

/* ------------------------------------------------------- bus time */

/* The bits of a classical base frame on the wire (ISO 11898-1): SOF,
 * identifier, RTR, IDE, r0, DLC, data and the CRC-15 (polynomial 0x4599)
 * with a stuff bit after every five equal bits, then the CRC delimiter,
 * ACK slot and delimiter, end of frame and intermission (13, unstuffed). */
static unsigned frame_bits(const struct can_frame *f)
{
	uint8_t bits[19 + 64 + 15];
	unsigned n = 0, dlc = f->can_dlc > 8 ? 8 : f->can_dlc;
	uint16_t crc = 0;

	bits[n++] = 0;
	for (int k = 10; k >= 0; k--)
		bits[n++] = (f->can_id >> k) & 1;
	bits[n++] = (f->can_id & CAN_RTR_FLAG) != 0;
	bits[n++] = 0;
	bits[n++] = 0;
	for (int k = 3; k >= 0; k--)
		bits[n++] = (dlc >> k) & 1;
	for (unsigned b = 0; b < dlc && !(f->can_id & CAN_RTR_FLAG); b++)
		for (int k = 7; k >= 0; k--)
			bits[n++] = (f->data[b] >> k) & 1;
	for (unsigned i = 0; i < n; i++) {
		bool next = bits[i] ^ ((crc >> 14) & 1);
		crc = (uint16_t)((crc << 1) & 0x7fff);
		if (next)
			crc ^= 0x4599;
	}
	for (int k = 14; k >= 0; k--)
		bits[n++] = (crc >> k) & 1;
	unsigned stuffed = n, run = 1;
	uint8_t last = bits[0];
	for (unsigned i = 1; i < n; i++) {
		run = bits[i] == last ? run + 1 : 1;
		last = bits[i];
		if (run == 5) {
			/* the complement goes in, and starts a run of its own */
			stuffed++;
			last = !last;
			run = 1;
		}
	}
	return stuffed + 13;
}

/* Waits until the frame f received at rx_ns, and the answer it gets, would
 * have crossed the bus (an answer of the same length: 8 data bytes). */
static void bus_time(const struct can_sim *s, const struct can_frame *f, uint64_t rx_ns)
{
	if (!(s->cfg.bitrate > 0) || f->can_id < 0x600 || f->can_id > 0x67f)
		return;
	uint64_t end = rx_ns + (uint64_t)(2.0 * frame_bits(f) / s->cfg.bitrate * 1e9);
	struct timespec ts = { (time_t)(end / 1000000000u), (long)(end % 1000000000u) };
	while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
		;
}

static void *serve(void *data)
{
	struct can_sim *s = data;

	while (!atomic_load(&s->quit)) {
		struct pollfd p[2] = { { s->fd, POLLIN, 0 }, { s->wake, POLLIN, 0 } };
		pthread_mutex_lock(&s->lock);
		int timeout = busy(s) ? 1 : 5;
		pthread_mutex_unlock(&s->lock);
		if (poll(p, 2, timeout) < 0 && errno != EINTR)
			break;
		if (p[1].revents) {
			uint64_t x;
			if (read(s->wake, &x, sizeof(x)) < 0)
				break;
		}
		if (p[0].revents & POLLIN) {
			struct can_frame f;
			ssize_t got = recv(s->fd, &f, sizeof(f), MSG_DONTWAIT);
			uint64_t rx = now_monotonic_ns();
			if (got == (ssize_t)sizeof(f)) {
				bus_time(s, &f, rx);
				can_sim_feed(s, &f);
			}
			else if (got == 0)
				break;  /* the client closed */
		} else if (p[0].revents & (POLLHUP | POLLERR)) {
			break;
		}
		pthread_mutex_lock(&s->lock);
		tick(s);
		for (unsigned i = 0; i < s->n_pending; i++)
			send_frame(s, &s->pending[i], true);
		s->n_pending = 0;
		pthread_mutex_unlock(&s->lock);
	}
	return NULL;
}

int can_sim_new(int fd, const struct can_sim_config *c, struct can_sim **out)
{
	struct can_sim *s = calloc(1, sizeof(*s));

	if (!s || c->n_nodes > CAN_SIM_MAX_NODES) {
		free(s);
		return -EINVAL;
	}
	s->fd = fd;
	s->wake = eventfd(0, EFD_CLOEXEC);
	s->cfg = *c;
	pthread_mutex_init(&s->lock, NULL);
	atomic_init(&s->quit, false);
	for (unsigned i = 0; i < c->n_nodes; i++) {
		struct sim_node *n = &s->nodes[i];
		n->id = c->nodes[i];
		n->device_type = c->device_type[i] ? c->device_type[i] : 0x00020192;
		n->nmt = CANOPEN_STATE_PRE_OPERATIONAL;
		n->heartbeat_on = true;
		n->hb_ms = (uint16_t)c->heartbeat_ms;
		n->next_hb_ns = now_monotonic_ns();
		n->state = CIA402_SWITCH_ON_DISABLED;
		n->reached = true;
		n->velocity = 1000;
		n->tp_kind = c->touch_probe[i];
	}
	s->edges = calloc(MAX_EDGES, sizeof(*s->edges));
	if (!s->edges) {
		can_sim_free(s);
		return -ENOMEM;
	}
	*out = s;
	return 0;
}

int can_sim_run(struct can_sim *s)
{
	int r = pthread_create(&s->thread, NULL, serve, s);
	s->running = r == 0;
	return -r;
}

static void wake(struct can_sim *s)
{
	uint64_t one = 1;
	if (write(s->wake, &one, sizeof(one)) < 0)
		return;
}

void can_sim_free(struct can_sim *s)
{
	if (!s)
		return;
	atomic_store(&s->quit, true);
	wake(s);
	if (s->running)
		pthread_join(s->thread, NULL);
	pthread_mutex_destroy(&s->lock);
	close(s->wake);
	close(s->fd);
	free(s->edges);
	free(s);
}

/* ------------------------------------------------------ injections */

#define WITH_NODE(s, id, body)                                 \
	do {                                                   \
		pthread_mutex_lock(&(s)->lock);                \
		struct sim_node *n = find((s), (id));          \
		if (n) {                                       \
			body;                                  \
		}                                              \
		pthread_mutex_unlock(&(s)->lock);              \
		wake(s);                                       \
	} while (0)

void can_sim_fault(struct can_sim *s, uint8_t node, uint16_t code, bool persistent)
{
	WITH_NODE(s, node, n->fault_persistent = persistent; enter_fault(s, n, code));
}

void can_sim_fault_on_move(struct can_sim *s, uint8_t node, uint16_t code)
{
	WITH_NODE(s, node, n->fault_on_move = code);
}

void can_sim_silence(struct can_sim *s, uint8_t node, bool silent)
{
	WITH_NODE(s, node, n->silent = silent);
}

void can_sim_heartbeat(struct can_sim *s, uint8_t node, bool on)
{
	WITH_NODE(s, node, n->heartbeat_on = on);
}

void can_sim_abort(struct can_sim *s, uint8_t node, uint16_t index, uint8_t sub, uint32_t code)
{
	WITH_NODE(s, node, n->abort_index = index; n->abort_sub = sub; n->abort_code = code);
}

void can_sim_garble(struct can_sim *s, uint8_t node, enum can_sim_garble g)
{
	WITH_NODE(s, node, n->garble = g);
}

void can_sim_reboot(struct can_sim *s, uint8_t node)
{
	WITH_NODE(s, node, reset_node(s, n, true));
}

void can_sim_homing_error(struct can_sim *s, uint8_t node, bool on)
{
	WITH_NODE(s, node, n->homing_error = on);
}

void can_sim_set_probe(struct can_sim *s, uint8_t node, int16_t value)
{
	WITH_NODE(s, node, n->probe = value);
}

void can_sim_link_lost(struct can_sim *s)
{
	pthread_mutex_lock(&s->lock);
	for (unsigned i = 0; i < s->cfg.n_nodes; i++) {
		struct sim_node *n = &s->nodes[i];
		if (n->state != CIA402_OPERATION_ENABLED)
			continue;
		n->state = CIA402_QUICK_STOP_ACTIVE;
		n->moving = n->homing = n->ack = false;
		n->reached = true;
		n->link_stops++;
	}
	pthread_mutex_unlock(&s->lock);
	wake(s);
}

void can_sim_heal(struct can_sim *s)
{
	pthread_mutex_lock(&s->lock);
	for (unsigned i = 0; i < s->cfg.n_nodes; i++) {
		struct sim_node *n = &s->nodes[i];
		n->fault_persistent = n->silent = n->homing_error = false;
		n->heartbeat_on = true;
		n->abort_code = 0;
		n->garble = CAN_SIM_GARBLE_NONE;
		n->fault_on_move = 0;
		n->fault_at_ns = 0;
	}
	pthread_mutex_unlock(&s->lock);
	wake(s);
}

void can_sim_error_frame(struct can_sim *s, uint32_t class, uint8_t ctrl)
{
	pthread_mutex_lock(&s->lock);
	if (s->n_pending < sizeof(s->pending) / sizeof(s->pending[0])) {
		struct can_frame *f = &s->pending[s->n_pending++];
		memset(f, 0, sizeof(*f));
		f->can_id = CAN_ERR_FLAG | class;
		f->can_dlc = CAN_ERR_DLC;
		f->data[1] = ctrl;
	}
	pthread_mutex_unlock(&s->lock);
	wake(s);
}

void can_sim_get(struct can_sim *s, uint8_t node, struct can_sim_node *out)
{
	memset(out, 0, sizeof(*out));
	WITH_NODE(s, node,
		  out->state = n->state; out->nmt = n->nmt; out->mode = n->mode;
		  out->controlword = n->cw; out->position = (int32_t)lround(n->pos);
		  out->target = n->target; out->velocity = n->velocity;
		  out->homing_method = n->method; out->quick_stops = n->quick_stops;
		  out->fault_resets = n->fault_resets; out->set_points = n->set_points;
		  out->homings = n->homings; out->resets = n->resets; out->homed = n->homed;
		  out->disable_ops = n->disable_ops; out->link_stops = n->link_stops;
		  out->moving = n->moving || n->homing;
		  out->tp_function = n->tp_function; out->tp_status = n->tp_status;
		  out->tp_positive = n->tp_positive; out->tp_negative = n->tp_negative;
		  out->tp_positive_count = n->tp_positive_count;
		  out->buffered_set_points = n->buffered_set_points;
		  out->first_set_point_ns = n->first_set_point_ns;
		  out->sdo_requests = n->sdo_requests);
}

void can_sim_trigger(struct can_sim *s, bool level)
{
	pthread_mutex_lock(&s->lock);
	tick(s);
	s->line_external = level;
	update_line(s);
	pthread_mutex_unlock(&s->lock);
	wake(s);
}

void can_sim_bounce(struct can_sim *s, bool on)
{
	pthread_mutex_lock(&s->lock);
	s->bounce = on;
	pthread_mutex_unlock(&s->lock);
}

size_t can_sim_edges(struct can_sim *s, struct can_sim_edge *out, size_t max)
{
	pthread_mutex_lock(&s->lock);
	size_t n = s->n_edges;
	size_t kept = n < MAX_EDGES ? n : MAX_EDGES;
	if (out && max)
		memcpy(out, s->edges, (kept < max ? kept : max) * sizeof(*out));
	pthread_mutex_unlock(&s->lock);
	return n;
}
