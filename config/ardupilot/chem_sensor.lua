-- chem_sensor.lua: an OSLIM chemical sensor on an ArduPilot vehicle.
--
-- Reads a chemical sensor and sends its reading as NAMED_VALUE_FLOAT "CHEM" on every MAVLink
-- port, where the OSLIM service on the companion computer reads it (DESIGN.md: no standard
-- MAVLink message carries a gas reading). Two sources, chosen by CHEM_SOURCE:
--   0  an analog pin (CHEM_PIN): reading = (volts - CHEM_OFFSET) * CHEM_SCALE
--   1  a serial sensor on a port with SERIALn_PROTOCOL = 28 (Scripting), the CHEM_SER_IDX-th such
--      port, that prints one decimal number per line ("12.5\r\n"):
--      reading = (number - CHEM_OFFSET) * CHEM_SCALE
-- Readings below zero are sent as 0. The rate is CHEM_RATE Hz. Nothing is sent until a first
-- valid reading exists; a serial sensor silent for 2 s stops the messages (one warning) until it
-- speaks again.
--
-- Install: copy to APM/scripts/ on the SD card (SITL: scripts/ in its working directory), set
-- SCR_ENABLE 1, reboot, then set CHEM_ENABLE 1 and the CHEM_* parameters (they appear after
-- the first boot with the script). See config/ardupilot/companion.parm.

local NAME = "CHEM"            -- the service's sensor.name (at most 10 characters)
local PARAM_TABLE_KEY = 87     -- must differ from the keys of other scripts on the vehicle
local PARAM_PREFIX = "CHEM_"
local MAV_SEVERITY_WARNING = 4
local MAV_SEVERITY_INFO = 6
local SERIAL_TIMEOUT_MS = 2000
local MAX_LINE = 32

-- name, default (index = position in this table)
local PARAMS = {
  { "ENABLE", 0 },     -- 1: read and send
  { "SOURCE", 0 },     -- 0: analog pin, 1: serial line sensor
  { "PIN", 15 },       -- analog pin number (board specific; e.g. 15 is ADC 6.6 V on many Pixhawks)
  { "OFFSET", 0 },     -- sensor output at zero concentration (V, or serial units)
  { "SCALE", 1 },      -- concentration per volt (or per serial unit)
  { "RATE", 5 },       -- sends per second, 0.1 .. 50
  { "SER_IDX", 0 },    -- which Scripting serial port (0 = the first SERIALn_PROTOCOL 28)
  { "BAUD", 9600 },    -- serial baud rate
}

assert(param:add_table(PARAM_TABLE_KEY, PARAM_PREFIX, #PARAMS), "CHEM: cannot add param table")
local p = {}
for index, entry in ipairs(PARAMS) do
  local name, default = entry[1], entry[2]
  assert(param:add_param(PARAM_TABLE_KEY, index, name, default), "CHEM: cannot add " .. name)
  p[name] = Parameter(PARAM_PREFIX .. name)
end

local analog_source = nil
local port = nil
local line = ""
local last_value = nil
local last_serial_ms = nil
local warned_silent = false

local function clamp(x, lo, hi)
  if x < lo then return lo end
  if x > hi then return hi end
  return x
end

local function period_ms()
  return math.floor(1000 / clamp(p.RATE:get(), 0.1, 50))
end

local function scaled(raw)
  local value = (raw - p.OFFSET:get()) * p.SCALE:get()
  if value < 0 then value = 0 end
  return value
end

local function read_analog()
  if not analog_source then
    analog_source = analog:channel()
    if not analog_source then
      gcs:send_text(MAV_SEVERITY_WARNING, "CHEM: no analog channel available")
      return nil
    end
  end
  analog_source:set_pin(math.floor(p.PIN:get()))
  return scaled(analog_source:voltage_average())
end

-- reads what has arrived; returns the newest complete number, or nil
local function read_serial(now_ms)
  if not port then
    port = serial:find_serial(math.floor(p.SER_IDX:get()))
    if not port then
      gcs:send_text(MAV_SEVERITY_WARNING, "CHEM: no serial port with SERIALn_PROTOCOL 28")
      return nil
    end
    port:begin(math.floor(p.BAUD:get()))
    port:set_flow_control(0)
    last_serial_ms = now_ms
  end
  local newest = nil
  local n = port:available()
  while n > 0 do
    local byte = port:read()
    n = n - 1
    if byte == 10 or byte == 13 then          -- end of line
      local number = tonumber(line)
      if number then newest = number end
      line = ""
    elseif #line < MAX_LINE then
      line = line .. string.char(byte)
    else                                      -- runaway line: start again
      line = ""
    end
  end
  if newest then
    last_serial_ms = now_ms
    warned_silent = false
    return scaled(newest)
  end
  if now_ms - last_serial_ms > SERIAL_TIMEOUT_MS then
    last_value = nil                          -- a dead sensor must not look like a steady one
    if not warned_silent then
      gcs:send_text(MAV_SEVERITY_WARNING, "CHEM: serial sensor silent")
      warned_silent = true
    end
  end
  return nil
end

local function update()
  if p.ENABLE:get() < 1 then
    return update, 1000
  end
  local now_ms = millis():tofloat()
  local value
  if p.SOURCE:get() >= 1 then
    value = read_serial(now_ms)
  else
    value = read_analog()
  end
  if value then last_value = value end
  if last_value then
    gcs:send_named_float(NAME, last_value)
  end
  return update, period_ms()
end

gcs:send_text(MAV_SEVERITY_INFO, "CHEM sensor script loaded")
return update, 1000
