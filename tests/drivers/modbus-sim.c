/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Simulated Modbus drives and a displacement sensor on libmodbus's server
 * API, served on a thread (TCP on 127.0.0.1 or RTU on a pty). */
#include <arpa/inet.h>
#include <errno.h>
#include <math.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <pty.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

#include "modbus-frame.h"
#include "modbus-sim.h"
#include "util-time.h"

enum { N_REGS = 0x200, N_CLIENTS = 4, N_FAULTS = 8, N_DATA = 8 };

struct drive {
	int unit;
	modbus_mapping_t *map;
	double from, to;                /* counts */
	uint64_t t0, t1;                /* ns of the motion */
	bool moving, homing, home_end;
	uint32_t alarm, last_cmd;
	int alarm_after;                /* raise alarm_pending at that start */
	uint32_t alarm_pending;
};

struct fault {
	int unit, code, count, reg;
	enum mbsim_fault kind;
};

struct mbsim {
	struct mbsim_config c;
	pthread_t thread;
	pthread_mutex_t lock;
	int wake[2];
	int listen_fd, clients[N_CLIENTS];
	int master_fd;
	modbus_t *ctx;
	struct drive drives[3];
	modbus_mapping_t *sensor;
	int orbit_forced;               /* a status set by the test, or -1 */
	struct fault faults[N_FAULTS];
	struct mbsim_stats stats;
};

/* ----------------------------------------------------------- values */

static int words(const struct mbsim *s)
{
	return s->c.map.wide ? 2 : 1;
}

static uint32_t get_value(const struct mbsim *s, const uint16_t *regs, int addr)
{
	return s->c.map.wide ? mb_get32(regs + addr, s->c.map.order) : regs[addr];
}

static void put_value(const struct mbsim *s, uint16_t *regs, int addr, uint32_t v)
{
	if (s->c.map.wide)
		mb_put32(regs + addr, v, s->c.map.order);
	else
		regs[addr] = (uint16_t)v;
}

/* ----------------------------------------------------------- drives */

static double drive_position(const struct drive *d, uint64_t t)
{
	if (!d->moving || t >= d->t1)
		return d->to;
	return d->from + (d->to - d->from) * (double)(t - d->t0) / (double)(d->t1 - d->t0);
}

static void drive_advance(struct mbsim *s, struct drive *d, uint64_t t)
{
	if (d->moving && t >= d->t1) {
		d->moving = false;
		if (d->homing)
			d->home_end = true;
		d->homing = false;
	}
}

static void drive_halt(struct drive *d, uint64_t t)
{
	d->to = round(drive_position(d, t));
	d->moving = d->homing = false;
}

static void drive_go(struct mbsim *s, struct drive *d, double target, double speed, uint64_t t)
{
	d->from = drive_position(d, t);
	d->to = target;
	double sec = fabs(target - d->from) / (speed > 0 ? speed : 1) * s->c.time_scale;
	d->t0 = t;
	d->t1 = t + (uint64_t)(sec * 1e9);
	d->moving = true;
}

static bool stop_held(const struct mbsim *s, const struct drive *d)
{
	return d->last_cmd >> s->c.map.bit_stop & 1;
}

/* Starts the operation of the data block. */
static void drive_start(struct mbsim *s, int k, uint64_t t)
{
	struct drive *d = &s->drives[k];
	const uint16_t *r = d->map->tab_registers;
	int n = words(s), base = s->c.map.reg_data;
	int32_t pos = (int32_t)get_value(s, r, base + 2 * n);

	if (d->alarm || stop_held(s, d))
		return;
	if (!s->c.map.wide)
		pos = (int16_t)pos;
	drive_go(s, d, pos, (double)(int32_t)get_value(s, r, base + 3 * n), t);
	s->stats.starts[k]++;
	if (d->alarm_after > 0 && --d->alarm_after == 0) {
		drive_halt(d, t);
		d->alarm = d->alarm_pending;
	}
}

static void drive_command(struct mbsim *s, int k, uint32_t cmd, uint64_t t)
{
	struct drive *d = &s->drives[k];
	const struct stage_map *m = &s->c.map;
	uint32_t rise = cmd & ~d->last_cmd;

	d->last_cmd = cmd;
	if (cmd >> m->bit_stop & 1) {
		if (rise >> m->bit_stop & 1)
			s->stats.stops[k]++;
		drive_halt(d, t);
		return;
	}
	if (rise >> m->bit_alm_rst & 1)
		d->alarm = 0;
	if (d->alarm)
		return;
	if (rise >> m->bit_zhome & 1) {
		d->home_end = false;
		d->homing = true;
		/* the drive's own homing speed: 20 ms for any distance */
		drive_go(s, d, 0, fabs(drive_position(d, t)) / 0.02 + 1, t);
		d->homing = true;
		s->stats.homings[k]++;
	}
	if (rise >> m->bit_start & 1)
		drive_start(s, k, t);
}

/* The registers a master reads, from the state at t. */
static void drive_publish(struct mbsim *s, struct drive *d, uint64_t t)
{
	const struct stage_map *m = &s->c.map;
	uint32_t st = 0;

	drive_advance(s, d, t);
	bool ready = !d->moving && !d->alarm && !stop_held(s, d);
	st |= (uint32_t)ready << m->bit_ready;
	st |= (uint32_t)d->moving << m->bit_busy;
	st |= (uint32_t)(!d->moving && !d->alarm) << m->bit_in_pos;
	st |= (uint32_t)(d->alarm != 0) << m->bit_alm;
	st |= (uint32_t)d->home_end << m->bit_home_end;
	put_value(s, d->map->tab_registers, m->reg_status, st);
	put_value(s, d->map->tab_registers, m->reg_position,
		  (uint32_t)(int32_t)llround(drive_position(d, t)));
	put_value(s, d->map->tab_registers, m->reg_alarm, d->alarm);
}

/* After a write to a drive: a trigger starts, a command acts. */
static void drive_written(struct mbsim *s, int k, int addr, int n, uint64_t t)
{
	struct drive *d = &s->drives[k];
	const struct stage_map *m = &s->c.map;
	int trig = m->reg_data + 7 * words(s);

	if (addr <= trig && trig < addr + n) {
		uint32_t v = get_value(s, d->map->tab_registers, trig);
		if (v == 1)
			drive_start(s, k, t);
		/* the drive clears the trigger once it took the data */
		put_value(s, d->map->tab_registers, trig, 0);
	}
	if (addr <= m->reg_command && m->reg_command < addr + n)
		drive_command(s, k, get_value(s, d->map->tab_registers, m->reg_command), t);
}

/* ----------------------------------------------------------- sensor */

enum { RF_TYPE = 1, RF_FIRMWARE, RF_SERIAL, RF_BASE, RF_RANGE, RF_VALUE };
#define RF_FULL_SCALE 16384
#define ORBIT_FLOAT_IMAGE 8000

/* RF60x: D normalised to the range, at its ends where the target is
 * beyond them (the detector's last pixel). */
static void rf60x_publish(struct mbsim *s, const double *pos)
{
	uint16_t *in = s->sensor->tab_input_registers;  /* address 1 first */
	double mm = -1;

	if (!s->c.sense_mm(s->c.sense_data, pos, &mm))
		mm = -1;
	double d = round(mm / s->c.rf_range_mm * RF_FULL_SCALE);
	in[RF_TYPE - 1] = 63;
	in[RF_FIRMWARE - 1] = 40;
	in[RF_SERIAL - 1] = 19999;
	in[RF_BASE - 1] = (uint16_t)s->c.rf_base_mm;
	in[RF_RANGE - 1] = (uint16_t)s->c.rf_range_mm;
	in[RF_VALUE - 1] = (uint16_t)(d < 0 ? 0 : d > RF_FULL_SCALE ? RF_FULL_SCALE : d);
}

static void put_float(uint16_t *w, float f, enum mb_word_order order)
{
	uint32_t v;

	memcpy(&v, &f, sizeof(v));
	mb_put32(w, v, order);
}

/* Orbit ACS: the probe's reading and its status, as integers and as
 * their float images, in both tables. */
static void orbit_publish(struct mbsim *s, const double *pos)
{
	double mm = 0;
	bool valid = s->c.sense_mm(s->c.sense_data, pos, &mm);
	int status = !valid || mm > s->c.orbit_range_mm ? 19 : mm < 0 ? 18 : 0;

	if (s->orbit_forced >= 0)
		status = s->orbit_forced;
	for (int tab = 0; tab < 2; tab++) {
		uint16_t *r = tab ? s->sensor->tab_registers : s->sensor->tab_input_registers;
		mb_put32(r + s->c.orbit_reading, (uint32_t)(int32_t)llround(mm * 1e4),
			 MB_HIGH_WORD_FIRST);
		put_float(r + s->c.orbit_reading + ORBIT_FLOAT_IMAGE, (float)mm, s->c.orbit_order);
		r[s->c.orbit_status] = (uint16_t)status;
		put_float(r + s->c.orbit_status + ORBIT_FLOAT_IMAGE, (float)status, s->c.orbit_order);
	}
}

/* Orbit ACS: a read that takes part of a two-register parameter. */
static bool orbit_splits(const struct mbsim *s, int addr, int n)
{
	const int two[] = { s->c.orbit_reading, s->c.orbit_reading + ORBIT_FLOAT_IMAGE,
			    s->c.orbit_status + ORBIT_FLOAT_IMAGE };

	for (size_t i = 0; i < sizeof(two) / sizeof(two[0]); i++) {
		bool first = addr <= two[i] && two[i] < addr + n;
		bool second = addr <= two[i] + 1 && two[i] + 1 < addr + n;
		if (first != second)
			return true;
	}
	return false;
}

static void sensor_publish(struct mbsim *s, uint64_t t)
{
	double pos[3] = { 0, 0, 0 };
	bool valid = true;

	for (int k = 0; k < 3; k++)
		if (s->drives[k].map)
			pos[k] = (double)llround(drive_position(&s->drives[k], t)) /
				 s->c.counts_per_unit[k];
	if (s->c.sensor_kind == MBSIM_SENSOR_RF60X) {
		rf60x_publish(s, pos);
		return;
	}
	if (s->c.sensor_kind == MBSIM_SENSOR_ORBIT_ACS) {
		orbit_publish(s, pos);
		return;
	}
	int32_t v = s->c.sense(s->c.sense_data, pos, &valid);
	for (int tab = 0; tab < 2; tab++) {
		uint16_t *r = tab ? s->sensor->tab_registers : s->sensor->tab_input_registers;
		mb_put32(r + MBSIM_SENSOR_VALUE, (uint32_t)v, MB_HIGH_WORD_FIRST);
		r[MBSIM_SENSOR_STATUS] = valid ? 1 : 0;
	}
}

/* --------------------------------------------------------- requests */

static struct fault *fault_for(struct mbsim *s, int unit, int addr, int n)
{
	for (int i = 0; i < N_FAULTS; i++) {
		struct fault *f = &s->faults[i];
		if (f->count == 0 || f->unit != unit || f->kind == MBSIM_ALARM)
			continue;
		if (f->reg >= 0 && !(addr <= f->reg && f->reg < addr + n))
			continue;
		if (f->count > 0)
			f->count--;
		return f;
	}
	return NULL;
}

/* An RTU answer with its CRC spoiled. */
static void send_garbled(struct mbsim *s, const uint8_t *req, modbus_mapping_t *m)
{
	uint8_t rsp[300];
	int fn = req[1], addr = req[2] << 8 | req[3], n = req[4] << 8 | req[5], len;

	rsp[0] = req[0];
	rsp[1] = (uint8_t)fn;
	if (fn == 3 || fn == 4) {
		const uint16_t *regs = fn == 3 ? m->tab_registers : m->tab_input_registers;
		rsp[2] = (uint8_t)(2 * n);
		for (int i = 0; i < n && addr + i < N_REGS; i++) {
			rsp[3 + 2 * i] = (uint8_t)(regs[addr + i] >> 8);
			rsp[4 + 2 * i] = (uint8_t)regs[addr + i];
		}
		len = 3 + 2 * n;
	} else {
		memcpy(rsp + 2, req + 2, 4);
		len = 6;
	}
	uint16_t crc = mbsim_crc16(rsp, (size_t)len) ^ 0x5a5a;
	rsp[len] = (uint8_t)crc;
	rsp[len + 1] = (uint8_t)(crc >> 8);
	if (write(s->master_fd, rsp, (size_t)len + 2) < 0)
		perror("modbus sim");
}

static modbus_mapping_t *unit_map(struct mbsim *s, int unit, int *drive)
{
	*drive = -1;
	for (int k = 0; k < 3; k++)
		if (s->drives[k].map && s->drives[k].unit == unit) {
			*drive = k;
			return s->drives[k].map;
		}
	return s->sensor && s->c.sensor_unit == unit ? s->sensor : NULL;
}

static void handle(struct mbsim *s, const uint8_t *req, int len)
{
	int hl = modbus_get_header_length(s->ctx), k;
	int unit = req[hl - 1], fn = req[hl];
	int addr = req[hl + 1] << 8 | req[hl + 2], n = req[hl + 3] << 8 | req[hl + 4];
	uint64_t t = now_monotonic_ns();

	pthread_mutex_lock(&s->lock);
	s->stats.requests++;
	modbus_mapping_t *m = unit_map(s, unit, &k);
	if (!m) {
		/* nobody there: an RTU bus stays silent, a gateway says so */
		if (!s->c.rtu)
			modbus_reply_exception(s->ctx, req, MODBUS_EXCEPTION_GATEWAY_TARGET);
		pthread_mutex_unlock(&s->lock);
		return;
	}
	if (fn == 6)
		n = 1;
	struct fault *f = fault_for(s, unit, addr, n);
	if (f && f->kind == MBSIM_DELAY) {
		struct timespec late = { f->code / 1000, (long)(f->code % 1000) * 1000000 };
		/* the answer says what the device holds when it is sent */
		pthread_mutex_unlock(&s->lock);
		nanosleep(&late, NULL);
		pthread_mutex_lock(&s->lock);
		t = now_monotonic_ns();
		f = NULL;
	}
	for (int i = 0; i < 3; i++)
		if (s->drives[i].map)
			drive_publish(s, &s->drives[i], t);
	if (m == s->sensor)
		sensor_publish(s, t);
	if (m == s->sensor && s->c.sensor_kind == MBSIM_SENSOR_ORBIT_ACS && (fn == 3 || fn == 4) &&
	    orbit_splits(s, addr, n) && !f)
		modbus_reply_exception(s->ctx, req, MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
	else if (f && f->kind == MBSIM_EXCEPTION)
		modbus_reply_exception(s->ctx, req, (unsigned)f->code);
	else if (f && f->kind == MBSIM_GARBLE && s->c.rtu)
		send_garbled(s, req, m);
	else if (!f || f->kind != MBSIM_SILENT) {
		modbus_reply(s->ctx, req, len, m);
		if (k >= 0 && (fn == 16 || fn == 6)) {
			drive_written(s, k, addr, n, t);
			drive_publish(s, &s->drives[k], t);
		}
	}
	pthread_mutex_unlock(&s->lock);
}

/* ------------------------------------------------------ serving TCP */

static void serve_client(struct mbsim *s, int i)
{
	uint8_t req[MODBUS_TCP_MAX_ADU_LENGTH];

	modbus_set_socket(s->ctx, s->clients[i]);
	int rc = modbus_receive(s->ctx, req);
	if (rc > 0) {
		handle(s, req, rc);
	} else if (rc < 0) {
		close(s->clients[i]);
		s->clients[i] = -1;
	}
}

static void serve_tcp(struct mbsim *s)
{
	for (;;) {
		struct pollfd p[2 + N_CLIENTS] = {
			{ .fd = s->wake[0], .events = POLLIN },
			{ .fd = s->listen_fd, .events = POLLIN },
		};
		for (int i = 0; i < N_CLIENTS; i++)
			p[2 + i] = (struct pollfd){ .fd = s->clients[i], .events = POLLIN };
		if (poll(p, 2 + N_CLIENTS, -1) < 0 && errno != EINTR)
			return;
		if (p[0].revents)
			return;
		/* connections the master closed free their slots first: a
		 * master that reconnects must find one */
		for (int i = 0; i < N_CLIENTS; i++)
			if (s->clients[i] >= 0 && p[2 + i].revents)
				serve_client(s, i);
		if (p[1].revents & POLLIN) {
			int fd = accept(s->listen_fd, NULL, NULL);
			for (int i = 0; fd >= 0 && i < N_CLIENTS; i++)
				if (s->clients[i] < 0) {
					s->clients[i] = fd;
					fd = -1;
				}
			if (fd >= 0)
				close(fd);
		}
	}
}

/* ------------------------------------------------------ serving RTU */

static void serve_rtu(struct mbsim *s)
{
	uint8_t buf[512];
	int got = 0;

	for (;;) {
		struct pollfd p[2] = {
			{ .fd = s->wake[0], .events = POLLIN },
			{ .fd = s->master_fd, .events = POLLIN },
		};
		/* a frame is over after a silence: drop a partial one */
		int rc = poll(p, 2, got ? 50 : -1);
		if (rc < 0 && errno != EINTR)
			return;
		if (p[0].revents)
			return;
		if (rc == 0) {
			got = 0;
			continue;
		}
		ssize_t n = read(s->master_fd, buf + got, sizeof(buf) - (size_t)got);
		if (n <= 0)
			continue;
		got += (int)n;
		int len = mbsim_rtu_request_length(buf, got);
		if (!len)
			continue;
		if (mbsim_crc16(buf, (size_t)len - 2) == (buf[len - 2] | buf[len - 1] << 8))
			handle(s, buf, len);
		memmove(buf, buf + len, (size_t)(got - len));
		got -= len;
	}
}

static void *serve(void *data)
{
	struct mbsim *s = data;

	if (s->c.rtu)
		serve_rtu(s);
	else
		serve_tcp(s);
	return NULL;
}

/* -------------------------------------------------------- lifecycle */

static int listen_loopback(int *fd, int *port)
{
	struct sockaddr_in a = { .sin_family = AF_INET, .sin_port = 0 };
	socklen_t len = sizeof(a);

	a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
	*fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
	if (*fd < 0 || bind(*fd, (struct sockaddr *)&a, sizeof(a)) < 0 || listen(*fd, 4) < 0 ||
	    getsockname(*fd, (struct sockaddr *)&a, &len) < 0)
		return -errno;
	*port = ntohs(a.sin_port);
	return 0;
}

static int open_pty(struct mbsim *s, char *path, size_t size)
{
	int slave;
	char name[128];
	struct termios t;

	if (openpty(&s->master_fd, &slave, name, NULL, NULL) < 0)
		return -errno;
	/* raw on both ends until the driver configures its side */
	tcgetattr(slave, &t);
	cfmakeraw(&t);
	tcsetattr(slave, TCSANOW, &t);
	/* keep the slave open so that the master never sees a hang-up
	 * between the driver's connections */
	s->listen_fd = slave;
	snprintf(path, size, "%s", name);
	return 0;
}

int mbsim_start(const struct mbsim_config *c, struct mbsim **out, char *address, size_t size)
{
	struct mbsim *s = calloc(1, sizeof(*s));
	int r;

	if (!s)
		return -ENOMEM;
	s->c = *c;
	s->listen_fd = s->master_fd = -1;
	for (int i = 0; i < N_CLIENTS; i++)
		s->clients[i] = -1;
	pthread_mutex_init(&s->lock, NULL);
	for (int k = 0; k < 3; k++) {
		s->drives[k].unit = c->drive_units[k];
		if (c->drive_units[k])
			s->drives[k].map = modbus_mapping_new_start_address(0, 0, 0, 0, 0, N_REGS, 0, 0);
	}
	s->orbit_forced = -1;
	if (c->sensor_unit && c->sensor_kind == MBSIM_SENSOR_RF60X) {
		s->sensor = modbus_mapping_new_start_address(0, 0, 0, 0, 10, 32, RF_TYPE, 6);
	} else if (c->sensor_unit && c->sensor_kind == MBSIM_SENSOR_ORBIT_ACS) {
		int top = (c->orbit_reading > c->orbit_status ? c->orbit_reading : c->orbit_status) +
			  ORBIT_FLOAT_IMAGE + 2;
		s->sensor = modbus_mapping_new_start_address(0, 0, 0, 0, 0, top, 0, top);
	} else if (c->sensor_unit) {
		s->sensor = modbus_mapping_new_start_address(0, 0, 0, 0, 0, 16, 0, 16);
	}
	if (pipe(s->wake) < 0)
		return -errno;
	if (c->rtu) {
		r = open_pty(s, address, size);
		s->ctx = modbus_new_rtu("/dev/null", 115200, 'E', 8, 1);
		if (r == 0)
			modbus_set_socket(s->ctx, s->master_fd);
	} else {
		int port = 0;
		r = listen_loopback(&s->listen_fd, &port);
		snprintf(address, size, "%d", port);
		s->ctx = modbus_new_tcp("127.0.0.1", port);
	}
	if (r == 0)
		r = -pthread_create(&s->thread, NULL, serve, s);
	if (r < 0) {
		fprintf(stderr, "modbus sim: %s\n", strerror(-r));
		return r;
	}
	*out = s;
	return 0;
}

void mbsim_stop(struct mbsim *s)
{
	if (!s)
		return;
	if (write(s->wake[1], "x", 1) < 0)
		perror("modbus sim");
	pthread_join(s->thread, NULL);
	/* the descriptors are ours: libmodbus must not close or reset them */
	modbus_set_socket(s->ctx, -1);
	modbus_free(s->ctx);
	for (int i = 0; i < N_CLIENTS; i++)
		if (s->clients[i] >= 0)
			close(s->clients[i]);
	if (s->listen_fd >= 0)
		close(s->listen_fd);
	if (s->master_fd >= 0)
		close(s->master_fd);
	close(s->wake[0]);
	close(s->wake[1]);
	for (int k = 0; k < 3; k++)
		modbus_mapping_free(s->drives[k].map);
	modbus_mapping_free(s->sensor);
	pthread_mutex_destroy(&s->lock);
	free(s);
}

void mbsim_inject(struct mbsim *s, int unit, enum mbsim_fault fault, int code, int count,
		  int reg)
{
	pthread_mutex_lock(&s->lock);
	if (fault == MBSIM_ALARM) {
		uint64_t t = now_monotonic_ns();
		for (int k = 0; k < 3; k++)
			if (s->drives[k].map && s->drives[k].unit == unit && count > 0) {
				s->drives[k].alarm_after = count;
				s->drives[k].alarm_pending = (uint32_t)code;
			} else if (s->drives[k].map && s->drives[k].unit == unit) {
				drive_halt(&s->drives[k], t);
				s->drives[k].alarm = (uint32_t)code;
			}
	}
	for (int i = 0; fault != MBSIM_ALARM && i < N_FAULTS; i++)
		if (s->faults[i].count == 0) {
			s->faults[i] = (struct fault){ unit, code, count, reg, fault };
			break;
		}
	pthread_mutex_unlock(&s->lock);
}

void mbsim_orbit_status(struct mbsim *s, int status)
{
	pthread_mutex_lock(&s->lock);
	s->orbit_forced = status;
	pthread_mutex_unlock(&s->lock);
}

void mbsim_clear_faults(struct mbsim *s)
{
	pthread_mutex_lock(&s->lock);
	memset(s->faults, 0, sizeof(s->faults));
	pthread_mutex_unlock(&s->lock);
}

void mbsim_stats(struct mbsim *s, struct mbsim_stats *out)
{
	uint64_t t = now_monotonic_ns();

	pthread_mutex_lock(&s->lock);
	*out = s->stats;
	for (int k = 0; k < 3; k++) {
		struct drive *d = &s->drives[k];
		if (!d->map)
			continue;
		drive_advance(s, d, t);
		out->position[k] = llround(drive_position(d, t)) / s->c.counts_per_unit[k];
		out->home_end[k] = d->home_end;
		out->stop_held[k] = stop_held(s, d);
	}
	pthread_mutex_unlock(&s->lock);
}
