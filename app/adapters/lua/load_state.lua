-- Read a city's state for one epoch in one call (a consistent snapshot, as a script runs alone).
-- KEYS[1] meta hash, KEYS[2] open tasks hash, KEYS[3] tasks revision, KEYS[4 .. 3+ARGV[1]] count hashes,
-- then visit sets.
-- ARGV[2] '' to read every key asked for; else the state revision and ARGV[5] the version the caller's
-- mirror holds (app/adapters/redis_mirror.py), the keys asked for being only those it lacks: when either
-- is not the city's, nothing but the meta is read and the reply's third item is 'stale' (read again, all).
-- ARGV[3] the mirror's tasks revision ('' none) and ARGV[4] its number of open tasks. An empty revision
-- matches nothing.
-- Returns {meta {version, last_time, last_epoch, rev}, tasks revision or false, open tasks (flat) or false
-- when the mirror's are current, then per count hash {flat fields, PTTL} and per visit set {its members
-- joined by ',', PTTL}} (one reply per set, not one per member).
local n_counts = tonumber(ARGV[1])
local meta = redis.call('HMGET', KEYS[1], 'version', 'last_time', 'last_epoch', 'rev')
local tasks_rev = redis.call('GET', KEYS[3])
if ARGV[2] ~= '' and (meta[4] ~= ARGV[2] or meta[1] ~= ARGV[5]) then
  return {meta, tasks_rev, 'stale'}
end
local out = {meta, tasks_rev}
if ARGV[3] ~= '' and tasks_rev == ARGV[3] and redis.call('HLEN', KEYS[2]) == tonumber(ARGV[4]) then
  out[3] = false
else
  out[3] = redis.call('HGETALL', KEYS[2])
end
for i = 4, 3 + n_counts do
  out[#out + 1] = {redis.call('HGETALL', KEYS[i]), redis.call('PTTL', KEYS[i])}
end
for i = 4 + n_counts, #KEYS do
  out[#out + 1] = {table.concat(redis.call('SMEMBERS', KEYS[i]), ','), redis.call('PTTL', KEYS[i])}
end
return out
