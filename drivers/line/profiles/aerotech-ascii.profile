asphd-line-profile 1
# Aerotech Ensemble controllers through their ASCII command interface
# (TCP socket 8000 or RS-232), after the Ensemble Help, "ASCII Command
# Interface" and the AeroBasic reference: a command ends with LF; every
# answer starts with the acknowledgement character, % success (with the
# value of a query after it), ! a command the controller does not take,
# # a command that faulted (AXISFAULT says why).
name aerotech-ascii
description "Aerotech Ensemble (ASCII command interface)"
reference "Aerotech Ensemble Help: ASCII Command Interface; AeroBasic commands"
role stage
tcp_port 8000
serial 115200 8 none 1
send_terminator "\n"
reply_terminator "\n"
axes X Y Z
decimals 6
unit mm
poll_ms 5
ack "%"

error_reply "!{*}" "Aerotech: the controller does not take the command (a syntax error, an unknown axis or argument)"
error_reply "#{*}"
error_query "AXISFAULT({axis})" "%{code}"
error_none 0
error_bits
error_format "Aerotech axis fault {code}: {text}"
error 1 "PositionErrorFault"
error 2 "OverCurrentFault"
error 4 "CwEndOfTravelLimitFault"
error 8 "CcwEndOfTravelLimitFault"
error 16 "CwSoftwareLimitFault"
error 32 "CcwSoftwareLimitFault"
error 64 "AmplifierFault"
error 128 "PositionFeedbackFault"
error 256 "VelocityFeedbackFault"
error 512 "HallSensorFault"
error 1024 "MaxVelocityCommandFault"
error 2048 "EmergencyStopFault"
error 4096 "VelocityErrorFault"

op connect
  # motion commands return at once; completion is polled
  send "WAIT MODE NOWAIT"
end

op enable
  send "ACKNOWLEDGEALL"
  send "ENABLE {axis}"
end

op home
  send "HOME {axis}"
  # AXISSTATUS: bit 1 homed, bit 3 move active
  wait "AXISSTATUS({axis})" "%{code}" mask 0xA 0x2
end

op move
  send "MOVEABS {axis} {target}"
  wait "AXISSTATUS({axis})" "%{code}" mask 0x8 0
end

op position
  query "PFBKPROG({axis})" "%{pos}"
end

op stop
  send "ABORT {axis}"
end
