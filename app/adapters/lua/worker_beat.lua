-- Record a fleet worker's heartbeat for one city (docs/FLEET.md, "Heartbeat and status").
-- KEYS[1] hash worker id -> beat JSON, KEYS[2] zset worker id by the time it was seen.
-- ARGV[1] worker id, ARGV[2] beat JSON, ARGV[3] its seen time, ARGV[4] the cutoff (beats seen before it
-- are dropped), ARGV[5] how long the city's beats are kept after this one, in ms.
redis.call('HSET', KEYS[1], ARGV[1], ARGV[2])
redis.call('ZADD', KEYS[2], ARGV[3], ARGV[1])
local old = redis.call('ZRANGEBYSCORE', KEYS[2], '-inf', '(' .. ARGV[4])
if #old > 0 then
  redis.call('HDEL', KEYS[1], unpack(old))
  redis.call('ZREM', KEYS[2], unpack(old))
end
redis.call('PEXPIRE', KEYS[1], ARGV[5])
redis.call('PEXPIRE', KEYS[2], ARGV[5])
return #old
