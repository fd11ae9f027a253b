asphd-line-profile 1
# A machine run by LinuxCNC, through linuxcncrsh (its text-mode network
# interface, port 5007), after the linuxcncrsh(1) manual page of LinuxCNC
# 2.9 and its server (src/emc/usr_intf/emcrsh.cc): requests end with CR
# LF, replies with CR LF; with verbose on every SET answers
# "SET <COMMAND> ACK" or "NAK", and GET ERROR says why.
name linuxcnc
description "LinuxCNC machine (linuxcncrsh)"
reference "linuxcncrsh(1), LinuxCNC 2.9; src/emc/usr_intf/emcrsh.cc"
role stage
tcp_port 5007
send_terminator "\r\n"
reply_terminator "\r\n"
axes X Y Z
decimals 6
unit mm
poll_ms 5

error_reply "SET {*} NAK"
error_query "get error" "ERROR {text}"
error_none_text "OK"
error_format "LinuxCNC error: {text}"

op connect
  # echo is on for a new connection: each request comes back first
  send "hello EMC asphd 1.1" ack "hello EMC asphd 1.1"
  read "HELLO ACK {*}"
  send "set echo off" ack "set echo off"
  send "set verbose on" ack "SET VERBOSE ACK"
  send "set enable EMCTOO" ack "SET ENABLE ACK"
end

op enable
  send "set estop off" ack "SET ESTOP ACK"
  send "set machine on" ack "SET MACHINE ACK"
end

op home
  send "set mode manual" ack "SET MODE ACK"
  send "set joint_home -1" ack "SET JOINT_HOME ACK"
  wait "get joint_homed" "JOINT_HOMED YES YES YES" busy "JOINT_HOMED {*}"
end

op move
  send "set mode mdi" ack "SET MODE ACK"
  send "set mdi G53 G0 {a0}{t0} {a1}{t1} {a2}{t2}" ack "SET MDI ACK"
  wait "get program_status" "PROGRAM_STATUS IDLE" busy "PROGRAM_STATUS RUNNING"
end

op position
  query "get abs_act_pos" "ABS_ACT_POS {p0} {p1} {p2} {*}"
end

op stop
  send "set abort"
end
