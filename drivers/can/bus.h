/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A CANopen client on one bus: the raw SocketCAN socket (or any descriptor
 * carrying one struct can_frame per message, such as a socketpair with a
 * simulated drive on the other end, or a unix socket to a gateway) behind
 * the drivers' transport, with expedited SDO transfers, NMT, the heartbeat
 * consumer and the bus's error frames. Every call takes a timeout; faults
 * come back as the driver ABI's codes with a reason naming the node.
 * Internal.
 */
#ifndef ASPH_CAN_BUS_H
#define ASPH_CAN_BUS_H

#include <stdbool.h>
#include <stdint.h>

#include "asph/error.h"
#include "protocol.h"

struct can_bus;

/*
 * iface is a network interface ("can0"), "fd:N", a descriptor already
 * open (duplicated; the caller keeps its own), or "unix:PATH", a
 * SOCK_SEQPACKET unix socket a gateway or simulator listens on, one
 * struct can_frame per datagram (connected anew by every open). The
 * interface's receive filter passes the SDO responses, EMCY and heartbeats
 * of nodes[0 .. n-1] and the error frames; the others are unfiltered. A
 * kernel without CAN fails with -ENODEV saying so, as does a path nothing
 * listens on.
 */
int can_bus_open(const char *iface, const uint8_t *nodes, unsigned n, struct can_bus **out,
		 struct asph_error *err);
void can_bus_free(struct can_bus *b);

/* Names a node in every reason ("x" gives "x (node 3)"). */
void can_bus_label(struct can_bus *b, uint8_t node, const char *label);
const char *can_bus_node_name(const struct can_bus *b, uint8_t node);

int can_bus_send(struct can_bus *b, const struct can_frame *f, unsigned timeout_ms,
		 struct asph_error *err);
int can_bus_nmt(struct can_bus *b, uint8_t command, uint8_t node, struct asph_error *err);

/* Expedited SDO transfers. -EPROTO for an abort (err has its CiA 301 text)
 * or a response that does not fit, -ETIMEDOUT without an answer. */
int can_bus_sdo_upload(struct can_bus *b, uint8_t node, uint16_t index, uint8_t sub,
		       uint32_t *value, unsigned timeout_ms, struct asph_error *err);
int can_bus_sdo_download(struct can_bus *b, uint8_t node, uint16_t index, uint8_t sub,
			 uint32_t value, uint8_t size, unsigned timeout_ms,
			 struct asph_error *err);

/* The abort code of the last transfer the node refused (0: it did not). */
uint32_t can_bus_last_abort(const struct can_bus *b);

/* Writes index:sub of each of nodes[0 .. n-1] at once, without checking
 * for earlier faults (a quick stop after one), and collects the answers
 * for at most timeout_ms. Returns how many nodes confirmed. */
int can_bus_sdo_download_all(struct can_bus *b, const uint8_t *nodes, unsigned n,
			     uint16_t index, uint8_t sub, uint32_t value, uint8_t size,
			     unsigned timeout_ms);

/* After can_bus_expect_bootup() (before an NMT reset), a boot-up message
 * is expected; wait_bootup waits until each of nodes[0 .. n-1] sent one.
 * At any other time a boot-up means the node restarted: a fault. */
void can_bus_expect_bootup(struct can_bus *b);
int can_bus_wait_bootup(struct can_bus *b, const uint8_t *nodes, unsigned n,
			unsigned timeout_ms, struct asph_error *err);

/* Watches node's heartbeat from now on: silent for longer than timeout_ms
 * is a lost node (-ENODEV); 0 stops watching. */
void can_bus_watch(struct can_bus *b, uint8_t node, unsigned timeout_ms);

/* Handles what arrives for ms (heartbeats, EMCY, error frames) and
 * reports any fault seen: a lost heartbeat, a node that restarted,
 * bus-off or error passive. A heartbeat is overdue only once every frame
 * that already arrived has been read. can_bus_check() does the same
 * without waiting. */
int can_bus_idle(struct can_bus *b, unsigned ms, struct asph_error *err);
int can_bus_check(struct can_bus *b, struct asph_error *err);

/* The last EMCY code of node (0 = none). */
uint16_t can_bus_last_emcy(const struct can_bus *b, uint8_t node);
/* Whether node's heartbeat was lost. */
bool can_bus_node_lost(const struct can_bus *b, uint8_t node);

/* Any thread: the waiting call and every later one return -ECANCELED;
 * then frames[0 .. n-1] are written at once, without waiting (a quick
 * stop that must not depend on the interrupted exchange). */
void can_bus_cancel(struct can_bus *b, const struct can_frame *frames, unsigned n);

#endif
