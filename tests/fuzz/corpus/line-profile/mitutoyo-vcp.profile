asphd-line-profile 1
# Mitutoyo gauges on a USB-ITN (or MIG-USB) cable in virtual COM port
# mode, after the data output specification of Mitutoyo's USB data output
# (for example the QM-Height manual No. 99MAF600B, 6.2.2 "USB Data Output
# Specifications"): 9600 bit/s, 8 data bits, no parity, 1 stop bit;
# the request "1" CR answers "01A", the sign and eight characters with a
# floating point, CR ("01A+0000.123"). The gauge's data button (or a
# foot switch on the cable) sends the same line unasked: trigger=operator.
name mitutoyo-vcp
description "Mitutoyo gauge on USB-ITN (virtual COM port)"
reference "Mitutoyo USB data output specification (QM-Height manual No. 99MAF600B, 6.2.2)"
role probe
serial 9600 8 none 1
send_terminator "\r"
reply_terminator "\r"
unit mm

op read
  query "1" "01A{value}"
end
