asphd-line-profile 1
# Sylvac gauges and indicators over the Opto RS232 cable (or a Sylvac USB
# virtual COM port), after Sylvac's remote command list (as printed in
# the instruments' manuals, e.g. the Sylvac Power manual, "Data format"
# and "Remote commands"): commands of 2 or 3 letters and CR; "?" answers
# the displayed value (sign, integer part, point, decimals, CR); errors
# answer "ERR" and a number, 3 being a value beyond the measuring range.
name sylvac
description "Sylvac gauge (Opto RS232)"
reference "Sylvac instrument manual, data format and remote commands (Sylvac Power manual, p. 15)"
role probe
serial 4800 7 even 2
send_terminator "\r"
reply_terminator "\r"
unit mm

error_format "Sylvac error {code}: {text}"
error 0 "sensor error"
error 1 "incorrect command"
error 2 "parity error"
error 3 "measuring range exceeded"
error_reply "ERR{code}"

op read
  query "?" "{value}" range "ERR3"
end
