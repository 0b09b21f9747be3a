-- Read a city's state for one epoch in one call (a consistent snapshot, as a script runs alone).
-- KEYS[1] meta hash, KEYS[2] open tasks hash, KEYS[3 .. 2+ARGV[1]] count hashes, then visit sets.
-- Returns {meta {version, last_time, last_epoch}, tasks (flat), counts (flat)..., visits...}, each visit
-- set as one string of its members joined by ',': thousands of sets, one reply each, not one per member.
local n_counts = tonumber(ARGV[1])
local out = {redis.call('HMGET', KEYS[1], 'version', 'last_time', 'last_epoch')}
out[2] = redis.call('HGETALL', KEYS[2])
for i = 3, 2 + n_counts do
  out[#out + 1] = redis.call('HGETALL', KEYS[i])
end
for i = 3 + n_counts, #KEYS do
  out[#out + 1] = table.concat(redis.call('SMEMBERS', KEYS[i]), ',')
end
return out
