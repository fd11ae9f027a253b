asphd-line-profile 1
# Keyence LK-G series laser displacement sensors (LK-G3000 controllers),
# RS-232C, after the LK-G Series User's Manual, chapter 5 "RS-232C"
# (LK-G-M-NO5-E). A command and its answer end with CR; "M1" outputs the
# measured value of OUT1 as "M1," and a sign with seven characters (the
# point where the settings put it); "+FFFFFF" or "-FFFFFF" is beyond the
# range; an error answers "ER,<command>,<code>".
name keyence-lk
description "Keyence LK-G laser displacement sensor"
reference "Keyence LK-G Series User's Manual, chapter 5 RS-232C (LK-G-M-NO5-E)"
role probe
serial 9600 8 none 1
send_terminator "\r"
reply_terminator "\r"
# the OUT number is the sensor's first axis id (axes option)
axes 1 2 3
unit mm

error_format "Keyence error {code}: {text}"
error 0 "command error"
error 1 "status error"
error 20 "command length error"
error 21 "parameter count error"
error 22 "invalid parameter error"
error 88 "timeout error"
error 99 "other error"
error_reply "ER,{*},{code}"

op read
  query "M{a0}" "M{a0},{value}" range "M{a0},{*}FFFFFF"
end
