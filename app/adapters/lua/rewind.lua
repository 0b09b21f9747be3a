-- Set the last epoch time of the meta hash KEYS[1] back to ARGV[1] (docs/DESIGN.md, "Rewind and reset").
-- Returns {'empty', version} | {'ahead', version, last} | {'rewound', version, last}.
local m = redis.call('HMGET', KEYS[1], 'version', 'last_time')
local version = m[1] or '0'
if not m[2] then
  return {'empty', version}
end
if tonumber(ARGV[1]) > tonumber(m[2]) then
  return {'ahead', version, m[2]}
end
redis.call('HSET', KEYS[1], 'last_time', ARGV[1])
return {'rewound', version, m[2]}
