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
};

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
		n->moving = n->homing = n->ack = false;
		n->homed = n->attained = false;
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
		n->moving = n->homing = false;
		n->reached = true;
		if (was == CIA402_OPERATION_ENABLED)
			n->ack = false;
		return;
	}
	bool rise = (cw & 0x10) && !(prev & 0x10), fall = !(cw & 0x10) && (prev & 0x10);
	if (n->mode == CIA402_MODE_PROFILE_POSITION) {
		if (fall)
			n->ack = false;
		if (rise && !n->ack) {
			n->ack = true;
			n->set_points++;
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
		if (instant || fabs(d) <= stepv) {
			n->pos = goal;
			if (n->homing) {
				finish_homing(n);
			} else {
				n->moving = false;
				n->reached = true;
			}
		} else {
			n->pos += d > 0 ? stepv : -stepv;
		}
	}
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
		return ABORT_READ_ONLY;
	default:
		break;
	}
	if (index == CIA402_HOMING_SPEEDS && sub == 0)
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
		    n->nmt != CANOPEN_STATE_STOPPED)
			answer(s, n, &ev.u.sdo);
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
			if (got == (ssize_t)sizeof(f))
				can_sim_feed(s, &f);
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
		  out->moving = n->moving || n->homing);
}
