/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asphd under request load with a scan running: 32 clients send
 * daemon.status as fast as they get answers. Reported: requests/s, p50 and
 * p99 latency, the scan's point rate with and without the load, and as the
 * baseline of what a C server does on this machine in the same run,
 * redis-benchmark -t ping (32 clients) against a local redis-server.
 * Targets: >= 30 % of Redis's requests/s, p99 < 5 ms, the point rate
 * lowered by < 5 %.
 *
 * Environment: ASPHD_BIN (the daemon), REDIS_SERVER and REDIS_BENCHMARK
 * (default: from PATH), ASPH_BENCH_SECONDS (load phase, default 5),
 * ASPH_BENCH_CONFIG (members added to the daemon's configuration, e.g.
 * "mqtt": {...}: bench-fleet.py's runs), ASPH_BENCH_NO_BASELINE (set: no
 * Redis, and no verdicts; a "figures:" line for the caller instead).
 */
#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <netinet/in.h>
#include <unistd.h>

#include "bench-common.h"

#define N_CLIENTS 32
#define MAX_SAMPLES (1u << 22)

static char sock_path[256];

static int connect_daemon(void)
{
	struct sockaddr_un sa = { .sun_family = AF_UNIX };
	int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);

	snprintf(sa.sun_path, sizeof(sa.sun_path), "%.100s", sock_path);
	if (fd < 0 || connect(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0) {
		if (fd >= 0)
			close(fd);
		return -1;
	}
	return fd;
}

/* Sends one request line and reads one response line into buf. */
static ssize_t rpc(int fd, const char *req, char *buf, size_t size)
{
	size_t n = strlen(req), got = 0;

	if (send(fd, req, n, MSG_NOSIGNAL) != (ssize_t)n)
		return -1;
	while (got == 0 || buf[got - 1] != '\n') {
		ssize_t k = recv(fd, buf + got, size - got - 1, 0);
		if (k <= 0)
			return -1;
		got += (size_t)k;
		if (got >= size - 1)
			return -1;
	}
	buf[got] = '\0';
	return (ssize_t)got;
}

static long long json_int_after(const char *text, const char *key)
{
	const char *p = strstr(text, key);

	return p ? atoll(p + strlen(key)) : -1;
}

/*
 * The load: 32 connections driven by one thread with epoll, as
 * redis-benchmark drives its clients, so that the figures compare servers
 * and not client threads waiting for a CPU. Each connection has one
 * request outstanding at a time.
 */
struct conn {
	int fd;
	double sent;
	char buf[8192];
	size_t got;
};

struct load_result {
	double *lat;
	size_t n;
	int failed;
};

static atomic_bool stop_load;
static const char status_req[] = "{\"jsonrpc\":\"2.0\",\"id\":1,\"method\":\"daemon.status\"}\n";

static int send_status(struct conn *c)
{
	c->sent = bench_now();
	c->got = 0;
	return send(c->fd, status_req, sizeof(status_req) - 1, MSG_NOSIGNAL) ==
	       (ssize_t)(sizeof(status_req) - 1) ? 0 : -1;
}

static void *load(void *data)
{
	struct load_result *res = data;
	struct conn conns[N_CLIENTS];
	struct epoll_event ev[N_CLIENTS];
	int ep = epoll_create1(EPOLL_CLOEXEC);

	for (int i = 0; i < N_CLIENTS; i++) {
		struct epoll_event e = { .events = EPOLLIN, .data.ptr = &conns[i] };
		conns[i].fd = connect_daemon();
		if (conns[i].fd < 0 || epoll_ctl(ep, EPOLL_CTL_ADD, conns[i].fd, &e) < 0 ||
		    send_status(&conns[i]) < 0) {
			res->failed = 1;
			return NULL;
		}
	}
	while (!atomic_load(&stop_load) && res->n < MAX_SAMPLES) {
		int k = epoll_wait(ep, ev, N_CLIENTS, 100);
		for (int i = 0; i < k; i++) {
			struct conn *c = ev[i].data.ptr;
			ssize_t r = recv(c->fd, c->buf + c->got, sizeof(c->buf) - c->got - 1, 0);
			if (r <= 0) {
				res->failed = 1;
				goto out;
			}
			c->got += (size_t)r;
			if (c->buf[c->got - 1] != '\n')
				continue;
			c->buf[c->got] = '\0';
			if (!strstr(c->buf, "\"result\"")) {
				res->failed = 1;
				goto out;
			}
			res->lat[res->n++] = bench_now() - c->sent;
			if (send_status(c) < 0) {
				res->failed = 1;
				goto out;
			}
		}
	}
out:
	for (int i = 0; i < N_CLIENTS; i++)
		close(conns[i].fd);
	close(ep);
	return NULL;
}

static int cmp_double(const void *a, const void *b)
{
	double x = *(const double *)a, y = *(const double *)b;

	return (x > y) - (x < y);
}

/* Points done of job 1, read on its own connection. */
static long long job_done(void)
{
	char buf[8192];
	int fd = connect_daemon();
	long long d = -1;

	if (fd < 0)
		return -1;
	if (rpc(fd, "{\"jsonrpc\":\"2.0\",\"id\":1,\"method\":\"job.get\",\"params\":{\"id\":1}}\n",
		buf, sizeof(buf)) > 0)
		d = json_int_after(buf, "\"done\":");
	close(fd);
	return d;
}

static double point_rate(double seconds)
{
	long long a = job_done();
	double t = bench_now();

	usleep((useconds_t)(seconds * 1e6));
	return (double)(job_done() - a) / (bench_now() - t);
}

static pid_t spawn(char *const argv[], const char *log)
{
	pid_t pid = fork();

	if (pid == 0) {
		FILE *f = freopen(log, "w", stdout);
		if (f)
			dup2(fileno(f), 2);
		execvp(argv[0], argv);
		_exit(127);
	}
	return pid;
}

static void stop(pid_t pid)
{
	int status;

	if (pid <= 0)
		return;
	kill(pid, SIGTERM);
	waitpid(pid, &status, 0);
}

static pid_t start_daemon(const char *asphd, const char *dir)
{
	const char *extra = getenv("ASPH_BENCH_CONFIG");
	char conf[512], state[512], log[512], buf[8192];
	pid_t pid;
	FILE *f;

	snprintf(conf, sizeof(conf), "%s/asphd.conf", dir);
	snprintf(state, sizeof(state), "%s/state", dir);
	snprintf(log, sizeof(log), "%s/asphd.log", dir);
	snprintf(sock_path, sizeof(sock_path), "%s/asphd.sock", dir);
	f = fopen(conf, "w");
	if (!f)
		return -1;
	/* A streaming optical probe at 20 kHz, in real time. */
	fprintf(f, "{\"instruments\":[{\"name\":\"mock\",\"stage\":{\"driver\":\"mock\","
		   "\"options\":{\"speed\":200}},\"probe\":{\"driver\":\"mock\",\"options\":"
		   "{\"rate\":20000,\"noise\":2}}}]%s%s}\n", extra ? ", " : "", extra ? extra : "");
	fclose(f);
	pid = spawn((char *const[]){ (char *)asphd, "--config", conf, "--socket", sock_path,
				     "--state-dir", state, NULL }, log);
	for (int i = 0; i < 400; i++) {
		int fd = connect_daemon();
		if (fd >= 0) {
			close(fd);
			int s2 = connect_daemon();
			rpc(s2, "{\"jsonrpc\":\"2.0\",\"id\":1,\"method\":\"job.submit\",\"params\":"
				"{\"lens\":\"strong\",\"plan\":{\"method\":\"fermat\",\"points\":3000000}}}\n",
			    buf, sizeof(buf));
			close(s2);
			return pid;
		}
		usleep(25000);
	}
	stop(pid);
	return -1;
}

/* redis-benchmark -t ping with 32 clients against a private redis-server;
 * returns the better of its two PING figures, or -1. */
static double redis_rps(const char *dir)
{
	const char *server = getenv("REDIS_SERVER") ? getenv("REDIS_SERVER") : "redis-server";
	const char *benchmark = getenv("REDIS_BENCHMARK") ? getenv("REDIS_BENCHMARK") : "redis-benchmark";
	struct sockaddr_in sa = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
	socklen_t len = sizeof(sa);
	char port[16], log[512], cmd[1024], line[512];
	double best = -1;
	int fd = socket(AF_INET, SOCK_STREAM, 0);
	pid_t pid;
	FILE *p;

	/* A free port: bind to 0, read it back, release it. */
	if (fd < 0 || bind(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0 ||
	    getsockname(fd, (struct sockaddr *)&sa, &len) < 0)
		return -1;
	snprintf(port, sizeof(port), "%d", ntohs(sa.sin_port));
	close(fd);
	snprintf(log, sizeof(log), "%s/redis.log", dir);
	pid = spawn((char *const[]){ (char *)server, "--port", port, "--bind", "127.0.0.1",
				     "--save", "", "--appendonly", "no", "--dir", (char *)dir, NULL },
		    log);
	for (int i = 0; i < 200; i++) {
		int c = socket(AF_INET, SOCK_STREAM, 0);
		sa.sin_port = htons((uint16_t)atoi(port));
		int ok = connect(c, (struct sockaddr *)&sa, sizeof(sa)) == 0;
		close(c);
		if (ok)
			break;
		usleep(25000);
	}
	snprintf(cmd, sizeof(cmd), "%s -h 127.0.0.1 -p %s -t ping -c %d -n 400000 -q 2>/dev/null",
		 benchmark, port, N_CLIENTS);
	p = popen(cmd, "r");
	while (p && fgets(line, sizeof(line), p)) {
		/* "PING_MBULK: 123456.78 requests per second, p50=..." (the line
		 * may carry the progress redraws before it) */
		char *seg = strrchr(line, '\r');
		char *q = strstr(seg ? seg + 1 : line, "PING_");
		char *colon = q ? strchr(q, ':') : NULL;
		if (colon && strstr(colon, "requests per second")) {
			double v = atof(colon + 1);
			if (v > best)
				best = v;
		}
	}
	if (p)
		pclose(p);
	stop(pid);
	return best;
}

int main(void)
{
	const char *asphd = getenv("ASPHD_BIN");
	const char *sec = getenv("ASPH_BENCH_SECONDS");
	double seconds = sec ? atof(sec) : 5;
	char dir[] = "/tmp/bench-daemon.XXXXXX";
	struct load_result lr = { 0 };
	pthread_t thread;
	double rps, p50, p99, redis, before, during, after, t0, t1;
	size_t n;
	int misses = 0;
	pid_t pid;

	if (!asphd) {
		printf("SKIP: ASPHD_BIN is not set\n");
		return 77;
	}
	if (!mkdtemp(dir))
		return 1;
	pid = start_daemon(asphd, dir);
	if (pid < 0) {
		fprintf(stderr, "asphd did not start (see %s/asphd.log)\n", dir);
		return 1;
	}
	usleep(1500000);   /* the plan is computed and the scan streams */
	before = point_rate(seconds);

	lr.lat = calloc(MAX_SAMPLES, sizeof(double));
	if (!lr.lat)
		return 1;
	t0 = bench_now();
	pthread_create(&thread, NULL, load, &lr);
	during = point_rate(seconds);
	atomic_store(&stop_load, true);
	pthread_join(thread, NULL);
	t1 = bench_now();
	after = point_rate(seconds);
	stop(pid);

	n = lr.n;
	qsort(lr.lat, n, sizeof(double), cmp_double);
	rps = (double)n / (t1 - t0);
	p50 = n ? lr.lat[n / 2] * 1e3 : 0;
	p99 = n ? lr.lat[(size_t)(0.99 * (double)(n - 1))] * 1e3 : 0;
	double p90 = n ? lr.lat[(size_t)(0.90 * (double)(n - 1))] * 1e3 : 0;
	double lmax = n ? lr.lat[n - 1] * 1e3 : 0;
	free(lr.lat);
	int failed = lr.failed;

	double base = (before + after) / 2;
	double drop = base > 0 ? 1 - during / base : 1;

	if (getenv("ASPH_BENCH_NO_BASELINE")) {
		char rm[64];
		printf("figures: rps %.1f p99_ms %.3f points_per_s %.1f points_per_s_loaded %.1f "
		       "failed %d\n", rps, p99, base, during, failed);
		snprintf(rm, sizeof(rm), "rm -rf %s", dir);
		if (system(rm) != 0)
			fprintf(stderr, "could not remove %s\n", dir);
		return failed;
	}
	redis = redis_rps(dir);

	printf("asphd daemon.status, %d clients, scan running: %.0f requests/s, p50 %.3f ms, "
	       "p90 %.3f ms, p99 %.3f ms, max %.1f ms%s\n", N_CLIENTS, rps, p50, p90, p99, lmax,
	       failed ? " (a client failed)" : "");
	if (redis > 0) {
		printf("redis-server PING, %d clients (redis-benchmark): %.0f requests/s\n", N_CLIENTS, redis);
		printf("throughput: %.1f %% of Redis (target >= 30 %%): %s\n", 100 * rps / redis,
		       rps >= 0.3 * redis ? "PASS" : "MISS");
		misses += rps < 0.3 * redis;
	} else {
		printf("redis-server/redis-benchmark not found: no baseline (install redis-server redis-tools)\n");
		misses++;
	}
	printf("latency p99 %.3f ms (target < 5 ms): %s\n", p99, p99 < 5 ? "PASS" : "MISS");
	printf("scan point rate: %.0f points/s without load (%.0f before, %.0f after), %.0f under load: "
	       "%.1f %% lower (target < 5 %%): %s\n", base, before, after, during, 100 * drop,
	       drop < 0.05 ? "PASS" : "MISS");
	misses += p99 >= 5;
	misses += drop >= 0.05;
	misses += failed;
	char rm[64];
	snprintf(rm, sizeof(rm), "rm -rf %s", dir);
	if (system(rm) != 0)
		fprintf(stderr, "could not remove %s\n", dir);
	return misses ? 1 : 0;
}
