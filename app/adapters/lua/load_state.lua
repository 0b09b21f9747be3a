-- Read a city's state for one epoch in one call (a consistent snapshot, as a script runs alone).
-- KEYS[1] meta hash, KEYS[2] open tasks hash, KEYS[3] tasks revision, KEYS[4 .. 3+ARGV[1]] count hashes,
-- then visit sets.
-- ARGV[2] the state revision the caller's mirror holds ('' none), ARGV[3] its tasks revision ('' none),
-- ARGV[4] its number of open tasks, ARGV[5] one character per count and visit key: '1' when the mirror
-- holds that key (app/adapters/redis_mirror.py). An empty revision matches nothing.
-- Returns {meta {version, last_time, last_epoch, rev}, tasks revision or false, open tasks (flat) or false
-- when the mirror's are current, then per count hash {flat fields, PTTL} and per visit set {its members
-- joined by ',', PTTL} (one reply per set, not one per member), or false for a key the mirror holds while
-- the city's revision is still the mirror's.
local n_counts = tonumber(ARGV[1])
local meta = redis.call('HMGET', KEYS[1], 'version', 'last_time', 'last_epoch', 'rev')
local held = ARGV[2] ~= '' and meta[4] == ARGV[2]
local tasks_rev = redis.call('GET', KEYS[3])
local out = {meta, tasks_rev}
if ARGV[3] ~= '' and tasks_rev == ARGV[3] and redis.call('HLEN', KEYS[2]) == tonumber(ARGV[4]) then
  out[3] = false
else
  out[3] = redis.call('HGETALL', KEYS[2])
end
local flags = ARGV[5]
for i = 4, #KEYS do
  if held and string.byte(flags, i - 3) == 49 then
    out[#out + 1] = false
  elseif i <= 3 + n_counts then
    out[#out + 1] = {redis.call('HGETALL', KEYS[i]), redis.call('PTTL', KEYS[i])}
  else
    out[#out + 1] = {table.concat(redis.call('SMEMBERS', KEYS[i]), ','), redis.call('PTTL', KEYS[i])}
  end
end
return out
