/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The simulated CiA 402 drives of can-sim.c as a process: a CAN gateway on
 * a SOCK_SEQPACKET unix socket, one struct can_frame per datagram, which
 * the CAN driver reaches with interface=unix:PATH. Every client connected
 * shares the bus (the drives' frames go to all of them). Faults are
 * injected on command or at the N-th frame the clients sent:
 *
 *   disconnect   the connections are closed and new ones refused; the
 *                drives react as to a lost master (0x6007: quick stop)
 *   stall        the drives go on hearing the bus but send nothing
 *   garbage      every frame of the drives is replaced by a malformed
 *                one: datagrams of the wrong length, unknown COB-IDs, SDO
 *                answers about another object or with a wrong command
 *                specifier or toggle, wrong lengths, error frames
 *   drive-fault  a drive goes to fault (statusword, 0x603F, EMCY) that a
 *                fault reset does not clear
 *
 * until "heal". Commands, one per line on stdin, each answered by one JSON
 * line on stdout: fault KIND [NODE [CODE]], heal, status, quit (also end of
 * input). "status" tells what the drives received since the fault (quick
 * stop, disable operation) and whether they move. --log FILE records the
 * connections, faults and stop commands as JSON lines.
 *
 *   can-sim-server --socket PATH [--nodes 1,2,3] [--heartbeat MS]
 *                  [--speed-factor F] [--bitrate BIT/S] [--trigger NODE:BIT]
 *                  [--touch-probe NODE:full|no-counter|none] [--fault KIND
 *                  --at N [--node ID] [--code HEX] [--garbage KIND]]
 *                  [--seed S] [--log FILE]
 *
 * The trigger line is wired to output BIT of 0x60FE:01 of NODE (by
 * default bit 16 of the first node, as the driver's defaults expect; 0:0
 * unwired) and to every drive's touch probe input.
 */
#include <errno.h>
#include <getopt.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include <linux/can/error.h>

#include "can-sim.h"
#include "util-time.h"

#define MAX_CONNS 8

enum fault { FAULT_NONE, FAULT_DISCONNECT, FAULT_STALL, FAULT_GARBAGE, FAULT_DRIVE, N_FAULTS };
static const char *const fault_names[N_FAULTS] = {
	"none", "disconnect", "stall", "garbage", "drive-fault"
};

/* What garbage replaces the drives' frames with ("mixed": any, per frame). */
enum garbage { G_LENGTH, G_COB_ID, G_SDO_INDEX, G_SDO_COMMAND, G_DLC, G_ERROR_FRAME, G_MIXED,
	       N_GARBAGE };
static const char *const garbage_names[N_GARBAGE] = {
	"length", "cob-id", "sdo-index", "sdo-command", "dlc", "error-frame", "mixed"
};

struct server {
	const char *path;
	int listen_fd, sim_fd;          /* sim_fd: our end of the sim's socketpair */
	int conns[MAX_CONNS];
	unsigned n_conns, connections;
	struct can_sim *sim;
	struct can_sim_config cfg;
	FILE *log;
	uint64_t t0_ns, rng;
	unsigned long long frames;      /* from the clients */
	/* the fault: scheduled at frame `at`, then active until heal */
	enum fault scheduled, active;
	unsigned long long at, fault_frame;
	uint8_t fault_node;
	uint16_t fault_code;
	enum garbage garbage;
	unsigned long long garbage_sent[N_GARBAGE];
	unsigned long long dropped;     /* no room at a client or at the drives */
	unsigned long long withheld;    /* by a stall */
	struct can_sim_node before[CAN_SIM_MAX_NODES];  /* at the fault */
	char line[512];
	size_t n_line;
	bool trigger_set;
	uint8_t tp_node[CAN_SIM_MAX_NODES], tp_kind[CAN_SIM_MAX_NODES];
	unsigned n_tp;
};

static uint32_t rnd(struct server *sv)
{
	/* xorshift64*: reproducible from --seed */
	sv->rng ^= sv->rng >> 12;
	sv->rng ^= sv->rng << 25;
	sv->rng ^= sv->rng >> 27;
	return (uint32_t)((sv->rng * 2685821657736338717ull) >> 32);
}

static void log_event(struct server *sv, const char *fmt, ...)
{
	va_list ap;

	if (!sv->log)
		return;
	fprintf(sv->log, "{\"t\": %.6f, ", (double)(now_monotonic_ns() - sv->t0_ns) * 1e-9);
	va_start(ap, fmt);
	vfprintf(sv->log, fmt, ap);
	va_end(ap);
	fputs("}\n", sv->log);
	fflush(sv->log);
}

/* ------------------------------------------------------- the clients */

static void close_conn(struct server *sv, unsigned i, const char *why)
{
	close(sv->conns[i]);
	sv->conns[i] = sv->conns[--sv->n_conns];
	log_event(sv, "\"event\": \"closed\", \"by\": \"%s\"", why);
}

/* Heartbeats are dropped for a client that does not read (a full CAN
 * queue); any other frame waits a while for room. */
static void to_clients(struct server *sv, const void *buf, size_t len, bool droppable)
{
	for (unsigned i = 0; i < sv->n_conns; i++) {
		struct pollfd p = { sv->conns[i], POLLOUT, 0 };
		if (!droppable && poll(&p, 1, 500) <= 0)
			continue;
		ssize_t w = send(sv->conns[i], buf, len, MSG_DONTWAIT | MSG_NOSIGNAL);
		if (w < 0)
			sv->dropped++;
	}
}

/* A malformed stand-in for f, of kind g. */
static void garble(struct server *sv, const struct can_frame *f, enum garbage g)
{
	union {
		struct can_frame f;
		unsigned char bytes[48];
	} m;
	size_t len = sizeof(m.f);
	uint8_t node = (uint8_t)(f->can_id & 0x7f) ? (uint8_t)(f->can_id & 0x7f) : 1;
	bool sdo = (f->can_id & ~0x7fu) == CANOPEN_COB_SDO_TX;

	if (g == G_MIXED)
		g = (enum garbage)(rnd(sv) % G_MIXED);
	sv->garbage_sent[g]++;
	m.f = *f;
	switch (g) {
	case G_LENGTH:
		/* 1 .. 47 bytes but a frame's 16: never 0, which reads as a close */
		len = 1 + rnd(sv) % (sizeof(m.bytes) - 1);
		if (len == sizeof(m.f))
			len++;
		for (size_t i = 0; i < len; i++)
			m.bytes[i] = (unsigned char)rnd(sv);
		if (len > sizeof(m.f))
			m.f = *f;       /* a real frame in front, junk after it */
		break;
	case G_COB_ID:
		/* a PDO, an extended or a remote frame: nothing the client asked for */
		memset(&m.f, 0, sizeof(m.f));
		m.f.can_dlc = (uint8_t)(rnd(sv) % 9);
		for (int i = 0; i < 8; i++)
			m.f.data[i] = (uint8_t)rnd(sv);
		switch (rnd(sv) % 3) {
		case 0: m.f.can_id = 0x180u + 0x80u * (rnd(sv) % 8) + node; break;
		case 1: m.f.can_id = CAN_EFF_FLAG | (CANOPEN_COB_SDO_TX + node) | (rnd(sv) & 0x1fff0000u); break;
		default: m.f.can_id = CAN_RTR_FLAG | (CANOPEN_COB_SDO_TX + node); break;
		}
		break;
	case G_SDO_INDEX:
		if (!sdo)
			canopen_sdo_frame(&m.f, node, false, SDO_UPLOAD, (uint16_t)(0x2000 + rnd(sv) % 0x4000),
					  0, rnd(sv), 4);
		else
			m.f.data[1 + rnd(sv) % 2] ^= (uint8_t)(1 + rnd(sv) % 255);
		break;
	case G_SDO_COMMAND: {
		/* a segment (with its toggle bit), a segmented or block transfer, a
		 * command specifier that does not exist, or an SDO answer of the
		 * other kind (a write confirmed for a read, a value for a write) */
		static const uint8_t cmds[] = { 0x10, 0x00, 0x1f, 0x41, 0xa0, 0xc1, 0xe0, 0xff };
		uint8_t cs = f->data[0] >> 5;
		if (sdo && rnd(sv) % 3 == 0) {
			m.f.data[0] = cs == 3 ? 0x4b : 0x60;
			break;
		}
		if (!sdo)
			canopen_sdo_frame(&m.f, node, false, SDO_DOWNLOAD, CIA402_STATUSWORD, 0, 0, 0);
		m.f.data[0] = cmds[rnd(sv) % sizeof(cmds)];
		break;
	}
	case G_DLC:
		if (!sdo)
			canopen_sdo_frame(&m.f, node, false, SDO_UPLOAD, CIA402_STATUSWORD, 0, 0x0237, 2);
		m.f.can_dlc = (uint8_t)(rnd(sv) % 2 ? rnd(sv) % 8 : 9 + rnd(sv) % 7);
		break;
	default: {
		/* bus-off, error passive, or a harmless class */
		static const uint32_t classes[] = { CAN_ERR_BUSOFF, CAN_ERR_CRTL, CAN_ERR_CRTL, CAN_ERR_PROT,
						    CAN_ERR_LOSTARB, CAN_ERR_ACK, CAN_ERR_RESTARTED };
		static const uint8_t ctrl[] = { CAN_ERR_CRTL_RX_PASSIVE, CAN_ERR_CRTL_TX_PASSIVE,
						CAN_ERR_CRTL_RX_WARNING, CAN_ERR_CRTL_RX_OVERFLOW };
		memset(&m.f, 0, sizeof(m.f));
		m.f.can_id = CAN_ERR_FLAG | classes[rnd(sv) % (sizeof(classes) / sizeof(classes[0]))];
		m.f.can_dlc = CAN_ERR_DLC;
		m.f.data[1] = ctrl[rnd(sv) % sizeof(ctrl)];
		break;
	}
	}
	to_clients(sv, m.bytes, len, !sdo);
}

/* A frame of the drives, as the fault lets it through. */
static void from_sim(struct server *sv)
{
	struct can_frame f;
	ssize_t got = recv(sv->sim_fd, &f, sizeof(f), MSG_DONTWAIT);

	if (got != (ssize_t)sizeof(f))
		return;
	bool heartbeat = (f.can_id & ~0x7fu) == CANOPEN_COB_HEARTBEAT;
	if (sv->active == FAULT_STALL)
		sv->withheld++;
	else if (sv->active == FAULT_GARBAGE)
		garble(sv, &f, sv->garbage);
	else
		to_clients(sv, &f, sizeof(f), heartbeat);
}

/* --------------------------------------------------------- faults */

static void inject(struct server *sv, enum fault kind)
{
	for (unsigned i = 0; i < sv->cfg.n_nodes; i++)
		can_sim_get(sv->sim, sv->cfg.nodes[i], &sv->before[i]);
	sv->active = kind;
	sv->scheduled = FAULT_NONE;
	sv->fault_frame = sv->frames;
	log_event(sv, "\"event\": \"fault\", \"kind\": \"%s\", \"frame\": %llu, \"node\": %u, "
		  "\"code\": %u, \"garbage\": \"%s\"", fault_names[kind], sv->frames, sv->fault_node,
		  sv->fault_code, garbage_names[sv->garbage]);
	switch (kind) {
	case FAULT_DISCONNECT:
		while (sv->n_conns)
			close_conn(sv, 0, "gateway");
		can_sim_link_lost(sv->sim);
		break;
	case FAULT_DRIVE:
		can_sim_fault(sv->sim, sv->fault_node, sv->fault_code, true);
		break;
	default:
		break;
	}
}

static void heal(struct server *sv)
{
	sv->active = sv->scheduled = FAULT_NONE;
	can_sim_heal(sv->sim);
	log_event(sv, "\"event\": \"heal\", \"frame\": %llu", sv->frames);
}

/* What the frame tells the drives to do, for the log. */
static void note_command(struct server *sv, const struct can_frame *f)
{
	struct can_event ev;

	if (canopen_decode(f, &ev) < 0 || ev.type != CAN_EV_SDO_REQUEST ||
	    ev.u.sdo.kind != SDO_DOWNLOAD || ev.u.sdo.index != CIA402_CONTROLWORD)
		return;
	uint16_t cw = (uint16_t)ev.u.sdo.value;
	const char *what = (cw & 0x06) == 0x02 ? "quick stop"
			   : (cw & 0x0f) == 0x07 ? "switch on or disable operation" : NULL;
	if (what)
		log_event(sv, "\"event\": \"command\", \"node\": %u, \"controlword\": %u, "
			  "\"command\": \"%s\", \"after_fault\": %s", ev.node, cw, what,
			  sv->active != FAULT_NONE ? "true" : "false");
}

static void from_client(struct server *sv, unsigned i)
{
	union {
		struct can_frame f;
		unsigned char bytes[sizeof(struct can_frame) + 1];
	} m;
	ssize_t got = recv(sv->conns[i], m.bytes, sizeof(m.bytes), MSG_DONTWAIT);

	if (got < 0 && (errno == EAGAIN || errno == EINTR))
		return;
	if (got <= 0) {
		close_conn(sv, i, "client");
		return;
	}
	if (got != (ssize_t)sizeof(m.f))
		return;         /* not a frame: the bus would not carry it */
	sv->frames++;
	if (sv->scheduled != FAULT_NONE && sv->frames >= sv->at) {
		inject(sv, sv->scheduled);
		if (sv->active == FAULT_DISCONNECT)
			return; /* the frame is lost with the link */
	}
	note_command(sv, &m.f);
	struct pollfd p = { sv->sim_fd, POLLOUT, 0 };
	if (poll(&p, 1, 500) > 0 && send(sv->sim_fd, &m.f, sizeof(m.f), MSG_DONTWAIT | MSG_NOSIGNAL) < 0)
		sv->dropped++;
}

static void accept_client(struct server *sv)
{
	int fd = accept4(sv->listen_fd, NULL, NULL, SOCK_CLOEXEC | SOCK_NONBLOCK);

	if (fd < 0)
		return;
	sv->connections++;
	if (sv->active == FAULT_DISCONNECT || sv->n_conns == MAX_CONNS) {
		log_event(sv, "\"event\": \"refused\", \"connection\": %u", sv->connections);
		close(fd);
		return;
	}
	sv->conns[sv->n_conns++] = fd;
	log_event(sv, "\"event\": \"connected\", \"connection\": %u", sv->connections);
}

/* ------------------------------------------------------- commands */

static void status(struct server *sv)
{
	printf("{\"frames\": %llu, \"connections\": %u, \"clients\": %u, \"fault\": \"%s\", "
	       "\"fault_frame\": %llu, \"dropped\": %llu, \"withheld\": %llu, \"garbage\": {",
	       sv->frames, sv->connections, sv->n_conns, fault_names[sv->active], sv->fault_frame,
	       sv->dropped, sv->withheld);
	for (int g = 0; g < G_MIXED; g++)
		printf("%s\"%s\": %llu", g ? ", " : "", garbage_names[g], sv->garbage_sent[g]);
	printf("}, \"trigger_edges\": %zu, \"nodes\": [", can_sim_edges(sv->sim, NULL, 0));
	for (unsigned i = 0; i < sv->cfg.n_nodes; i++) {
		struct can_sim_node n, *b = &sv->before[i];
		can_sim_get(sv->sim, sv->cfg.nodes[i], &n);
		printf("%s{\"node\": %u, \"state\": \"%s\", \"moving\": %s, \"homed\": %s, "
		       "\"position\": %d, \"quick_stops\": %u, \"disable_ops\": %u, \"link_stops\": %u, "
		       "\"set_points\": %u, \"enabled_at_fault\": %s, \"moving_at_fault\": %s, "
		       "\"stops_since_fault\": %u, \"set_points_since_fault\": %u}",
		       i ? ", " : "", sv->cfg.nodes[i], cia402_state_name(n.state),
		       n.moving ? "true" : "false", n.homed ? "true" : "false", n.position,
		       n.quick_stops, n.disable_ops, n.link_stops, n.set_points,
		       b->state == CIA402_OPERATION_ENABLED ? "true" : "false",
		       b->moving ? "true" : "false",
		       (n.quick_stops - b->quick_stops) + (n.disable_ops - b->disable_ops) +
		       (n.link_stops - b->link_stops), n.set_points - b->set_points);
	}
	printf("]}\n");
}

static int parse_fault(const char *name)
{
	for (int k = 1; k < N_FAULTS; k++)
		if (strcmp(name, fault_names[k]) == 0)
			return k;
	return -1;
}

static int parse_garbage(const char *name)
{
	for (int g = 0; g < N_GARBAGE; g++)
		if (strcmp(name, garbage_names[g]) == 0)
			return g;
	return -1;
}

/* One command line; false to quit. */
static bool command(struct server *sv, char *line)
{
	char word[32] = "", kind[32] = "";
	unsigned node = 0, code = 0;
	int n = sscanf(line, "%31s %31s %u %x", word, kind, &node, &code);

	if (n <= 0)
		return true;
	if (strcmp(word, "quit") == 0) {
		printf("{\"ok\": true}\n");
		return false;
	}
	if (strcmp(word, "status") == 0) {
		status(sv);
	} else if (strcmp(word, "heal") == 0) {
		heal(sv);
		printf("{\"ok\": true}\n");
	} else if (strcmp(word, "fault") == 0 && parse_fault(kind) > 0) {
		if (n >= 3)
			sv->fault_node = (uint8_t)node;
		if (n >= 4)
			sv->fault_code = (uint16_t)code;
		inject(sv, (enum fault)parse_fault(kind));
		printf("{\"ok\": true}\n");
	} else {
		printf("{\"error\": \"unknown command: %.40s\"}\n", word);
	}
	fflush(stdout);
	return true;
}

/* false at the end of input or on quit */
static bool from_stdin(struct server *sv)
{
	ssize_t got = read(0, sv->line + sv->n_line, sizeof(sv->line) - 1 - sv->n_line);

	if (got < 0)
		return errno == EINTR || errno == EAGAIN;
	if (got == 0)
		return false;
	sv->n_line += (size_t)got;
	sv->line[sv->n_line] = 0;
	char *nl;
	while ((nl = strchr(sv->line, '\n'))) {
		*nl = 0;
		if (!command(sv, sv->line))
			return false;
		sv->n_line -= (size_t)(nl + 1 - sv->line);
		memmove(sv->line, nl + 1, sv->n_line + 1);
	}
	if (sv->n_line == sizeof(sv->line) - 1)
		sv->n_line = 0;         /* a line too long for any command */
	return true;
}

/* ---------------------------------------------------------- setup */

static void usage(FILE *f)
{
	fprintf(f, "usage: can-sim-server --socket PATH [--nodes 1,2,3] [--heartbeat MS]\n"
		   "         [--speed-factor F] [--bitrate BIT/S] [--trigger NODE:BIT]\n"
		   "         [--touch-probe NODE:KIND]\n"
		   "         [--fault disconnect|stall|garbage|drive-fault --at N\n"
		   "         [--node ID] [--code HEX] [--garbage KIND]] [--seed S] [--log FILE]\n"
		   "garbage kinds: length, cob-id, sdo-index, sdo-command, dlc, error-frame, mixed\n"
		   "touch probe kinds: full, no-counter, none\n"
		   "commands on stdin: fault KIND [NODE [CODE]], heal, status, quit\n");
}

static int parse_nodes(struct can_sim_config *c, const char *list)
{
	char buf[64], *save = NULL;

	snprintf(buf, sizeof(buf), "%s", list);
	c->n_nodes = 0;
	for (char *t = strtok_r(buf, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
		char *end;
		long id = strtol(t, &end, 10);
		if (*end || id < 1 || id > CANOPEN_NODE_MAX || c->n_nodes == CAN_SIM_MAX_NODES)
			return -1;
		c->nodes[c->n_nodes++] = (uint8_t)id;
	}
	return c->n_nodes ? 0 : -1;
}

/* NODE:BIT of the trigger output */
static int parse_trigger(struct can_sim_config *c, const char *arg)
{
	unsigned node, bit;
	char tail;

	if (sscanf(arg, "%u:%u%c", &node, &bit, &tail) != 2 || node > CANOPEN_NODE_MAX || bit > 31)
		return -1;
	c->trigger_node = (uint8_t)node;
	c->trigger_bit = (uint8_t)bit;
	return 0;
}

/* NODE:KIND of a drive's touch probe, applied once the nodes are known */
static int parse_touch_probe(struct server *sv, const char *arg)
{
	static const char *const kinds[] = { "full", "no-counter", "none" };
	unsigned node;
	int at = 0;

	if (sscanf(arg, "%u:%n", &node, &at) != 1 || !at || node > CANOPEN_NODE_MAX ||
	    sv->n_tp == CAN_SIM_MAX_NODES)
		return -1;
	for (uint8_t k = 0; k < 3; k++)
		if (!strcmp(arg + at, kinds[k])) {
			sv->tp_node[sv->n_tp] = (uint8_t)node;
			sv->tp_kind[sv->n_tp++] = k;
			return 0;
		}
	return -1;
}

static int apply_touch_probes(struct server *sv)
{
	for (unsigned t = 0; t < sv->n_tp; t++) {
		unsigned i = 0;
		while (i < sv->cfg.n_nodes && sv->cfg.nodes[i] != sv->tp_node[t])
			i++;
		if (i == sv->cfg.n_nodes)
			return -1;
		sv->cfg.touch_probe[i] = sv->tp_kind[t];
	}
	return 0;
}

static int parse_args(struct server *sv, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "socket", required_argument, NULL, 's' }, { "nodes", required_argument, NULL, 'n' },
		{ "heartbeat", required_argument, NULL, 'b' },
		{ "speed-factor", required_argument, NULL, 'v' },
		{ "bitrate", required_argument, NULL, 'B' },
		{ "fault", required_argument, NULL, 'f' }, { "at", required_argument, NULL, 'a' },
		{ "node", required_argument, NULL, 'N' }, { "code", required_argument, NULL, 'c' },
		{ "garbage", required_argument, NULL, 'g' }, { "seed", required_argument, NULL, 'r' },
		{ "log", required_argument, NULL, 'l' }, { "help", no_argument, NULL, 'h' },
		{ "trigger", required_argument, NULL, 't' },
		{ "touch-probe", required_argument, NULL, 'p' },
		{ 0 }
	};
	int c, k;

	while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
		switch (c) {
		case 's': sv->path = optarg; break;
		case 'n':
			if (parse_nodes(&sv->cfg, optarg) < 0)
				return -1;
			break;
		case 'b': sv->cfg.heartbeat_ms = (unsigned)atoi(optarg); break;
		case 'v': sv->cfg.speed_factor = atof(optarg); break;
		case 'B':
			sv->cfg.bitrate = atof(optarg);
			if (!(sv->cfg.bitrate >= 0)) {
				fprintf(stderr, "can-sim-server: --bitrate: '%s' is no bit rate\n", optarg);
				return -1;
			}
			break;
		case 't':
			if (parse_trigger(&sv->cfg, optarg) < 0)
				return -1;
			sv->trigger_set = true;
			break;
		case 'p':
			if (parse_touch_probe(sv, optarg) < 0)
				return -1;
			break;
		case 'f':
			if ((k = parse_fault(optarg)) < 0)
				return -1;
			sv->scheduled = (enum fault)k;
			break;
		case 'a': sv->at = strtoull(optarg, NULL, 10); break;
		case 'N': sv->fault_node = (uint8_t)atoi(optarg); break;
		case 'c': sv->fault_code = (uint16_t)strtoul(optarg, NULL, 16); break;
		case 'g':
			if ((k = parse_garbage(optarg)) < 0)
				return -1;
			sv->garbage = (enum garbage)k;
			break;
		case 'r': sv->rng = strtoull(optarg, NULL, 10) * 0x9e3779b97f4a7c15ull + 1; break;
		case 'l':
			sv->log = fopen(optarg, "a");
			if (!sv->log) {
				perror(optarg);
				return -1;
			}
			break;
		case 'h': usage(stdout); exit(0);
		default: return -1;
		}
	}
	if (!sv->path || optind != argc || (sv->scheduled != FAULT_NONE && sv->at == 0) ||
	    apply_touch_probes(sv) < 0)
		return -1;
	if (!sv->trigger_set) {
		sv->cfg.trigger_node = sv->cfg.nodes[0];
		sv->cfg.trigger_bit = 16;
	}
	return 0;
}

static int listen_on(struct server *sv)
{
	struct sockaddr_un addr = { .sun_family = AF_UNIX };

	if (strlen(sv->path) >= sizeof(addr.sun_path)) {
		fprintf(stderr, "%s: path too long\n", sv->path);
		return -1;
	}
	memcpy(addr.sun_path, sv->path, strlen(sv->path));
	sv->listen_fd = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
	unlink(sv->path);
	if (sv->listen_fd < 0 || bind(sv->listen_fd, (struct sockaddr *)&addr, sizeof(addr)) < 0 ||
	    listen(sv->listen_fd, 4) < 0) {
		perror(sv->path);
		return -1;
	}
	return 0;
}

static int start_sim(struct server *sv)
{
	int pair[2];

	if (socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, pair) < 0)
		return -1;
	sv->sim_fd = pair[0];
	if (can_sim_new(pair[1], &sv->cfg, &sv->sim) < 0) {
		close(pair[1]);
		return -1;
	}
	return can_sim_run(sv->sim);
}

static void serve(struct server *sv)
{
	for (;;) {
		struct pollfd p[3 + MAX_CONNS] = {
			{ 0, POLLIN, 0 }, { sv->listen_fd, POLLIN, 0 }, { sv->sim_fd, POLLIN, 0 },
		};
		unsigned n = sv->n_conns;
		for (unsigned i = 0; i < n; i++)
			p[3 + i] = (struct pollfd){ sv->conns[i], POLLIN, 0 };
		if (poll(p, 3 + n, 100) < 0 && errno != EINTR)
			return;
		if (p[2].revents & POLLIN)
			from_sim(sv);
		/* from the last, as a closed one moves the last into its place */
		for (unsigned i = n; i-- > 0;)
			if (p[3 + i].revents && i < sv->n_conns && sv->conns[i] == p[3 + i].fd)
				from_client(sv, i);
		if (p[1].revents & POLLIN)
			accept_client(sv);
		if (p[0].revents && !from_stdin(sv))
			return;
	}
}

int main(int argc, char **argv)
{
	struct server sv = { .rng = 0x2545f4914f6cdd1dull, .fault_node = 1, .fault_code = 0x7121,
			     .garbage = G_MIXED };
	int r = 1;

	sv.cfg.n_nodes = 3;
	for (unsigned i = 0; i < 3; i++)
		sv.cfg.nodes[i] = (uint8_t)(i + 1);
	sv.cfg.heartbeat_ms = 20;
	sv.cfg.speed_factor = 1;
	if (parse_args(&sv, argc, argv) < 0) {
		usage(stderr);
		return 2;
	}
	signal(SIGPIPE, SIG_IGN);
	sv.t0_ns = now_monotonic_ns();
	if (listen_on(&sv) == 0 && start_sim(&sv) == 0) {
		log_event(&sv, "\"event\": \"listening\", \"socket\": \"%s\"", sv.path);
		printf("{\"ready\": true}\n");
		fflush(stdout);
		serve(&sv);
		r = 0;
	}
	while (sv.n_conns)
		close_conn(&sv, 0, "gateway");
	can_sim_free(sv.sim);
	if (sv.sim_fd > 0)
		close(sv.sim_fd);
	if (sv.listen_fd > 0) {
		close(sv.listen_fd);
		unlink(sv.path);
	}
	if (sv.log)
		fclose(sv.log);
	return r;
}
