/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <arpa/inet.h>
#include <errno.h>
#include <grp.h>
#include <stdbool.h>
#include <string.h>
#include <sys/stat.h>

#include "account.h"
#include "asph-driver/instrument.h"
#include "devices.h"

/* One option of an instrument's stage or probe, as the policy sees it. */
struct use {
	const char *instrument, *role, *option;
	const char *text;       /* the value as text */
	int64_t number;
};

typedef void (*use_fn)(const struct use *u, FILE *out, void *data);

/* Whether the driver talks TCP (a "transport" of "tcp", or none given). */
static const char *transport_of(const struct asph_driver *drv, const struct asph_option_value *v)
{
	for (size_t k = 0; k < drv->n_options; k++)
		if (!strcmp(drv->options[k].name, "transport"))
			return v[k].s;
	return NULL;
}

static void each_option(const char *name, const char *role, const struct asph_options *o,
			use_fn fn, FILE *out, void *data)
{
	const struct asph_driver *drv = asph_options_driver(o);
	const struct asph_option_value *v = asph_options_values(o);
	const char *transport = transport_of(drv, v);

	for (size_t k = 0; k < drv->n_options; k++) {
		const char *opt = drv->options[k].name;
		char buf[256];
		struct use u = { .instrument = name, .role = role, .option = opt,
				 .text = asph_option_value_format(&v[k], buf, sizeof(buf)),
				 .number = v[k].i };
		/* A serial device of a driver that is set to TCP is not used,
		 * nor a host of one set to a serial line. */
		if (transport && !strcmp(opt, "device") && !strcmp(transport, "tcp"))
			continue;
		if (transport && !strcmp(opt, "host") && strcmp(transport, "tcp"))
			continue;
		fn(&u, out, data);
	}
}

static void each_use(const struct instruments *ins, use_fn fn, FILE *out, void *data)
{
	for (size_t i = 0; i < instruments_count(ins); i++) {
		const struct instrument *in = instruments_get(ins, i);
		each_option(in->name, "stage", in->config->stage_options, fn, out, data);
		each_option(in->name, "probe", in->config->probe_options, fn, out, data);
	}
}

struct systemd_state {
	bool dialout;           /* a device node belongs to the group dialout */
	bool hidraw, usb;       /* hidraw and USB devices found by id */
};

static bool numeric_address(const char *s)
{
	unsigned char buf[sizeof(struct in6_addr)];

	return inet_pton(AF_INET, s, buf) == 1 || inet_pton(AF_INET6, s, buf) == 1;
}

static void systemd_line(const struct use *u, FILE *out, void *data)
{
	struct systemd_state *st = data;
	bool node = !strcmp(u->option, "device") || !strcmp(u->option, "path");

	if (node && !strncmp(u->text, "/dev/", 5)) {
		struct stat sb;
		char group[64];
		fprintf(out, "# %s, %s: %s\nDeviceAllow=%s rw\n", u->instrument, u->role, u->option,
			u->text);
		if (stat(u->text, &sb) == 0 && account_group_name(sb.st_gid, group, sizeof(group)) == 0 &&
		    !strcmp(group, "dialout"))
			st->dialout = true;
	} else if (!strcmp(u->option, "host") && u->text[0]) {
		if (numeric_address(u->text))
			fprintf(out, "# %s, %s: host\nIPAddressAllow=%s\n", u->instrument, u->role,
				u->text);
		else
			fprintf(out, "# %s, %s: host %s is a name: IPAddressAllow= takes its "
				"address or network\n", u->instrument, u->role, u->text);
	} else if (!strcmp(u->option, "vendor_id") && u->number) {
		st->usb = true;
		st->hidraw = true;
	}
}

static void udev_line(const struct use *u, FILE *out, void *data)
{
	const int64_t *vendor = data;

	/* vendor_id comes before product_id in the drivers' tables. */
	if (!strcmp(u->option, "vendor_id")) {
		*(int64_t *)data = u->number;
	} else if (!strcmp(u->option, "product_id") && *vendor) {
		fprintf(out, "# %s, %s\n", u->instrument, u->role);
		fprintf(out, "SUBSYSTEM==\"usb\", ENV{DEVTYPE}==\"usb_device\", "
			"ATTR{idVendor}==\"%04llx\", ATTR{idProduct}==\"%04llx\", GROUP=\"asphd\", "
			"MODE=\"0660\"\n", (long long)*vendor, (long long)u->number);
		fprintf(out, "SUBSYSTEM==\"hidraw\", ATTRS{idVendor}==\"%04llx\", "
			"ATTRS{idProduct}==\"%04llx\", GROUP=\"asphd\", MODE=\"0660\"\n",
			(long long)*vendor, (long long)u->number);
		if (u->number)
			*(int64_t *)data = 0;
	} else if ((!strcmp(u->option, "device") || !strcmp(u->option, "path")) &&
		   !strncmp(u->text, "/dev/", 5)) {
		fprintf(out, "# %s, %s: %s is a node the daemon opens by name: give it to "
			"the group asphd with a rule that matches its device\n", u->instrument,
			u->role, u->text);
	}
}

int devices_policy(const struct instruments *ins, const char *kind, FILE *out)
{
	if (!strcmp(kind, "systemd")) {
		struct systemd_state st = { 0 };
		fprintf(out, "# /etc/systemd/system/asphd.service.d/devices.conf, from asphd "
			"--device-policy=systemd:\n# only the devices and hosts the "
			"instruments name (docs/daemon.md, \"Devices\").\n[Service]\n"
			"DeviceAllow=\nIPAddressAllow=localhost\n"
			"# TCP clients of tcp_listen: add their networks, e.g.\n"
			"#IPAddressAllow=192.0.2.0/24\n");
		each_use(ins, systemd_line, out, &st);
		if (st.usb)
			fprintf(out, "# USB and HID devices found by vendor and product id\n"
				"DeviceAllow=char-usb_device rw\nDeviceAllow=char-hidraw rw\n");
		fprintf(out, "SupplementaryGroups=\n%s", st.dialout
			? "# a serial device of the group dialout\nSupplementaryGroups=dialout\n" : "");
		return 0;
	}
	if (!strcmp(kind, "udev")) {
		int64_t vendor = 0;
		fprintf(out, "# /etc/udev/rules.d/69-asphd-local.rules, from asphd "
			"--device-policy=udev:\n# the USB and HID devices the instruments name. "
			"To allow only these, mask the shipped\n# rules: ln -s /dev/null "
			"/etc/udev/rules.d/70-asphd.rules\n");
		each_use(ins, udev_line, out, &vendor);
		return 0;
	}
	return -EINVAL;
}
