asphd-line-profile 1
# PI controllers speaking GCS 2.0 (C-884, C-863, C-663, E-873, E-727 ...),
# after PI's "GCS 2.0 commands" reference as printed in the controllers'
# user manuals (docs/driver-line.md names the documents). One command a
# line, LF; set commands answer nothing, errors wait in ERR?; a multi-line
# answer ends each line but the last with a space before the LF.
name pi-gcs
description "PI GCS 2.0 motion controller"
reference "PI GCS 2.0 command reference (C-884 user manual MS244E)"
role stage
tcp_port 50000
serial 115200 8 none 1
send_terminator "\n"
reply_terminator "\n"
continuation " "
axes 1 2 3
decimals 7
unit mm
poll_ms 5

error_query "ERR?" "{code}"
error_none 0
error_format "PI error {code}: {text}"
error 1 "parameter syntax error"
error 2 "unknown command"
error 3 "command length out of limits"
error 5 "unallowable move attempted on unreferenced axis, or move attempted with servo off"
error 7 "position out of limits"
error 8 "velocity out of limits"
error 10 "controller was stopped by command"
error 15 "invalid axis identifier"
error 17 "parameter out of range"
error 22 "axis identifier specified more than once"
error 23 "illegal axis"
error 24 "incorrect number of parameters"
error 25 "invalid floating point number"
error 26 "parameter missing"
error 31 "axis has no reference sensor"

op connect
  # nothing left from a previous session: read and clear the error
  query "ERR?" "{code}"
end

op enable
  send "SVO {axis} 1" check
end

op velocity
  send "VEL {axis} {speed}" check
end

op home
  send "FRF {axis}" check
  # #7: controller ready (0xB1) once the reference moves are done
  wait "\x07" "\xB1" busy "\xB0"
  wait "FRF? {axis}" "{axis}=1" busy "{axis}=0"
  check
end

op move
  send "MOV {a0} {t0} {a1} {t1} {a2} {t2}"
  check
  # #5: no axis moving
  wait "\x05" "0" busy "{hex}"
  wait "ONT? {axis}" "{axis}=1" busy "{axis}=0"
end

op position
  # one answer of three lines: continued lines end with a space
  query "POS? {a0} {a1} {a2}" "{a0}={p0}\n{a1}={p1}\n{a2}={p2}"
end

op stop
  send "STP"
end
