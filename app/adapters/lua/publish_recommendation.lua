-- Publish a fleet-sizing recommendation if its version is the current one plus one (docs/FLEET.md).
-- KEYS[1] current hash {version, record}, KEYS[2] history list (newest first).
-- ARGV[1] the record's version, ARGV[2] the record's JSON, ARGV[3] how many history entries to keep.
-- Returns {'published', version} | {'version_mismatch', current version}.
local current = tonumber(redis.call('HGET', KEYS[1], 'version') or '0')
if tonumber(ARGV[1]) ~= current + 1 then
  return {'version_mismatch', tostring(current)}
end
redis.call('HSET', KEYS[1], 'version', ARGV[1], 'record', ARGV[2])
redis.call('LPUSH', KEYS[2], ARGV[2])
redis.call('LTRIM', KEYS[2], 0, tonumber(ARGV[3]) - 1)
return {'published', ARGV[1]}
