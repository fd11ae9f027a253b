asphd-line-profile 1
# Newport ESP301 (and ESP300) motion controllers, after the "ESP301
# Integrated 3-Axis Motion Controller/Driver User's Manual", section 3
# (remote mode) and its command reference: commands are the axis number,
# two letters and a parameter ("1PA12.5"), ended by CR; queries answer a
# line ended by CR LF. Errors wait in the error buffer (TE?); an
# axis-specific code is 100 x the axis plus the error.
name newport-esp
description "Newport ESP301 motion controller"
reference "Newport ESP301 User's Manual, section 3 remote mode and command reference"
role stage
tcp_port 5001
serial 19200 8 none 1 rtscts
send_terminator "\r"
reply_terminator "\r\n"
axes 1 2 3
decimals 6
unit mm
poll_ms 5

error_query "TE?" "{code}"
error_none 0
error_format "Newport error {code}: {text}"
error 6 "COMMAND DOES NOT EXIST"
error 7 "PARAMETER OUT OF RANGE"
error 9 "AXIS NUMBER OUT OF RANGE"
error 13 "MOTOR NOT ENABLED"
error 37 "AXIS NUMBER MISSING"
error 38 "COMMAND PARAMETER MISSING"
error 106 "AXIS-1 POSITIVE SOFTWARE LIMIT DETECTED"
error 107 "AXIS-1 NEGATIVE SOFTWARE LIMIT DETECTED"
error 206 "AXIS-2 POSITIVE SOFTWARE LIMIT DETECTED"
error 207 "AXIS-2 NEGATIVE SOFTWARE LIMIT DETECTED"
error 306 "AXIS-3 POSITIVE SOFTWARE LIMIT DETECTED"
error 307 "AXIS-3 NEGATIVE SOFTWARE LIMIT DETECTED"

op connect
  # an error left from before is not this session's
  query "TE?" "{code}"
end

op enable
  send "{axis}MO" check
end

op velocity
  send "{axis}VA{speed}" check
end

op home
  send "{axis}OR" check
  wait "{axis}MD?" "1" busy "0"
  check
end

op move
  send "{axis}PA{target}" check
  wait "{axis}MD?" "1" busy "0"
end

op position
  query "{axis}TP" "{pos}"
end

op stop
  send "{axis}ST"
end
